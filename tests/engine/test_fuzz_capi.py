"""The C ABI fuzz (capi_fuzz.py) in a child process: every entry point returns a status with a
message for null pointers, wrong and huge counts, NaN and out-of-range values; nothing crashes."""

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
RUN = ("import sys; sys.path[:0] = [{tests!r}, {here!r}]; import conftest, capi_fuzz; "
       "sys.exit(1 if capi_fuzz.fuzz({calls}, {seed}) else 0)")


def test_every_entry_point_survives_the_fuzz():
    code = RUN.format(tests=str(HERE.parent), here=str(HERE), calls=60, seed=1)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    last_call = proc.stderr.strip().splitlines()[-1:] or [""]
    assert proc.returncode == 0, f"exit {proc.returncode} after {last_call[0]}\n{proc.stdout[-3000:]}"
    assert "fuzzed" in proc.stdout and ", 0 failures" in proc.stdout
