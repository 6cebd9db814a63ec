"""Machine facts printed at the top of every benchmark (shared by bench_*.py)."""

from __future__ import annotations

import datetime
import hashlib
import os
import platform
import subprocess
from pathlib import Path

import numpy as np

from haptic_hand.engine import native

REPO = Path(__file__).resolve().parents[1]


def machine_info(watched=("native", "addon/engine")) -> dict:
    """CPU, cores, load, versions, commit (flagging uncommitted changes under `watched`) and the
    native library measured: what a reader needs to compare two runs."""
    cpu, physical = platform.processor() or platform.machine(), set()
    try:
        entry = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines() + [""]:
            key, _, value = line.partition(":")
            key, value = key.strip(), value.strip()
            if key == "model name":
                cpu = value
            elif key in ("physical id", "core id"):
                entry[key] = value
            elif not key and entry:
                physical.add((entry.get("physical id"), entry.get("core id")))
                entry = {}
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", *watched],
                               capture_output=True, text=True, check=True).stdout.strip()
        commit += f" ({' or '.join(watched)} has uncommitted changes)" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    library = str(native.library()._name)
    return {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "physical_cores": len(physical) or None,
        "usable_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "git_commit": commit,
        "library": library,
        "library_sha1": hashlib.sha1(Path(library).read_bytes()).hexdigest()[:12],
        "library_built": datetime.datetime.fromtimestamp(Path(library).stat().st_mtime).astimezone()
        .isoformat(timespec="seconds"),
    }


def print_machine(info: dict) -> None:
    print("== Machine")
    print(f"CPU:      {info['cpu']}")
    print(f"cores:    {info['logical_cores']} logical, {info['physical_cores']} physical, "
          f"{info['usable_cores']} usable by this process (the world step uses up to two: contact.threads)")
    if info["load_average"]:
        print("load:     " + " ".join(f"{x:.2f}" for x in info["load_average"])
              + " (1/5/15 min; anything else running skews the times)")
        if info["load_average"][0] > 1.5:
            print("WARNING:  the machine is busy (1-min load above 1.5): expect slower, noisier times")
    print(f"Python:   {info['python']}   numpy: {info['numpy']}")
    print(f"OS:       {info['platform']}")
    print(f"date:     {info['date']}")
    print(f"commit:   {info['git_commit']}")
    print(f"library:  {info['library']} (sha1 {info['library_sha1']}, built {info['library_built']})")
