"""Haptic rendering (issue 4): the felt force against physics the test knows independently.
The hand is the procedural hand with the sample scenes' stored tets, so runs repeat exactly;
every session runs offline (virtual time, the haptic loop in lockstep with the visual loop)."""

import math
from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import native, native_session, params, scene as scenes, session, simulate

SAMPLES = Path(simulate.__file__).parent / "sample_scenes"


def hand_scene(gravity=(0.0, 0.0, 0.0), coupling_stiffness=2000.0, **haptics) -> scenes.Scene:
    sc = scenes.load(SAMPLES / "hand_wave.json")
    sc.data["gravity"] = list(gravity)
    sc.data["coupling"]["stiffness"] = coupling_stiffness
    sc.data["haptics"].update({"enabled": True, **haptics})
    return sc


class Rig:
    """A scene's world with a haptic session on it, optionally a flat wall at the palm."""

    def __init__(self, sc: scenes.Scene, wall_gap: float | None = None, wall_friction: float = 0.5):
        self.world, self.hand, self.model, _, _ = simulate.build_world(sc)
        self.com = np.array(self.model.info()["handle_com"])
        self.mass = float(self.model.lumped_masses().sum())
        if wall_gap is not None:
            # the palm faces -x: a wall wall_gap beyond its outermost point
            self.wall_x = self.world.surface(self.hand)[:, 0].min() - wall_gap
            self.world.add_plane([self.wall_x, 0, 0], [1, 0, 0], friction=wall_friction)
        self.sc = sc
        self.session = session.create(self.world, self.hand, sc, log_capacity=400_000)

    def simulated_user(self, times, offsets, **arm):
        params = {"arm_mass": 1.0, "arm_stiffness": 300.0, "arm_damping": 20.0, **arm}
        self.session.device_simulated(np.asarray(times, float), self.com + np.asarray(offsets, float), **params)

    def run(self, seconds: float) -> dict:
        self.session.run_offline(int(round(seconds / self.sc.dt)))
        return native_session.log_arrays(self.session.read_log())


def test_at_rest_without_gravity_the_felt_force_is_zero():
    rig = Rig(hand_scene())
    rig.simulated_user([0.0], [[0, 0, 0]])
    log = rig.run(1.0)
    assert len(log["t"]) == 1000  # one row per haptic step: 1 kHz for 1 s
    assert np.abs(log["force"]).max() < 1e-9
    assert np.abs(log["torque"]).max() < 1e-9


def test_with_gravity_the_still_device_carries_the_hands_weight():
    rig = Rig(hand_scene(gravity=(0.0, 0.0, -9.81)))
    rig.simulated_user([0.0], [[0, 0, 0]])
    log = rig.run(2.0)
    felt = log["force"][-300:].mean(axis=0)  # the last 0.3 s
    weight = rig.mass * 9.81
    assert felt[2] == pytest.approx(-weight, rel=0.01)
    assert np.hypot(felt[0], felt[1]) < 0.01 * weight


def test_in_free_space_the_felt_force_is_the_hands_inertia():
    """A device shaken along x at 1 Hz: the hand follows, so the user feels F = -M a, plus a
    little damping in phase with the velocity. M is the flesh's mass plus the handle's (Eq. 3
    gives the handle the captured nodes' mass again, as its own rigid body)."""
    rig = Rig(hand_scene())
    amplitude, omega = 0.01, 2 * math.pi * 1.0
    t = np.arange(0, 4.0 + 1e-9, 0.005)
    rig.session.device_playback(t, rig.com + np.outer(amplitude * np.sin(omega * t), [1, 0, 0]))
    log = rig.run(4.0)
    steady = log["t"] > 1.0
    tt = log["t"][steady]
    a = -amplitude * omega**2 * np.sin(omega * tt)
    v = amplitude * omega * np.cos(omega * tt)
    coef, *_ = np.linalg.lstsq(np.column_stack([a, v]), log["force"][steady, 0], rcond=None)
    inertia = rig.mass + rig.model.info()["handle_mass"]
    assert coef[0] == pytest.approx(-inertia, rel=0.05)


def test_pushing_a_wall_the_felt_stiffness_is_the_coupling_in_series_with_the_contact():
    """Quasi-static push into a wall: the device sees the virtual coupling in series with the
    hand's own stiffness against the wall (the springs' force on the visual-loop handle against
    the handle's position, measured in the same run): 1/k = 1/k_vc + 1/k_contact."""
    k_vc = 2000.0
    rig = Rig(hand_scene(coupling_stiffness=k_vc), wall_gap=0.002)
    # the user's target goes 2 cm into the wall over 4 s: slow enough to be quasi-static
    rig.simulated_user([0.0, 0.2, 4.2, 5.0], [[0, 0, 0], [0, 0, 0], [-0.02, 0, 0], [-0.02, 0, 0]],
                       arm_stiffness=2000.0)
    handle_x, spring_fx = [], []
    for _ in range(int(round(4.2 / rig.sc.dt))):
        rig.session.run_offline(1)
        p, _, f, _ = rig.world.hand_state(rig.hand)
        handle_x.append(p[0])
        spring_fx.append(f[0])
    log = native_session.log_arrays(rig.session.read_log())
    handle_x, spring_fx = np.array(handle_x), np.array(spring_fx)
    late = slice(len(handle_x) // 2, None)  # well into the wall
    k_contact = -np.polyfit(handle_x[late], spring_fx[late], 1)[0]
    in_window = (log["t"] >= late.start * rig.sc.dt)
    k_felt = np.polyfit(log["device_position"][in_window, 0], log["force"][in_window, 0], 1)[0]
    k_series = 1.0 / (1.0 / k_vc + 1.0 / k_contact)
    assert k_contact > 50.0  # the wall is really pushing back
    assert -k_felt == pytest.approx(k_series, rel=0.10)


def wall_push(linearized: bool, k_vc: float) -> dict:
    rig = Rig(hand_scene(coupling_stiffness=k_vc, linearized=linearized), wall_gap=0.002)
    rig.simulated_user([0.0, 0.3, 1.0, 5.0], [[0, 0, 0], [0, 0, 0], [-0.02, 0, 0], [-0.02, 0, 0]], arm_damping=2.0)
    log = rig.run(5.0)
    dx = log["proxy_position"] - log["device_position"]
    log["coupling_energy"] = 0.5 * k_vc * (dx**2).sum(axis=1)
    return log


def test_stiffest_coupling_on_a_wall_stays_stable_with_linearization_and_not_without():
    k_max = params.by_json("coupling.stiffness").soft_max  # the stiffest coupling a session takes
    lin = wall_push(True, k_max)
    per_second = [slice(i * 1000, (i + 1) * 1000) for i in range(5)]
    energy = [lin["coupling_energy"][s].max() for s in per_second]
    wobble = [lin["force"][s, 0].std() for s in per_second]
    # bounded energy and no growing oscillation: after the push settles every second is calmer
    assert all(np.isfinite(lin["force"]).ravel())
    assert energy[4] <= energy[2] * 1.01 and energy[3] <= energy[1] * 1.01
    assert wobble[4] <= wobble[2] + 1e-6 and wobble[2] < 0.05 * abs(lin["force"][per_second[2], 0].mean())
    # the comparison docs/haptics.md shows: feedback from the 30 Hz handle alone keeps ringing
    off = wall_push(False, k_max)
    off_wobble = [off["force"][s, 0].std() for s in per_second]
    assert off_wobble[2] > 10 * wobble[2]


def quat_from_rotation_vector(theta: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(theta))
    if angle == 0.0:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.concatenate([math.sin(angle / 2) * theta / angle, [math.cos(angle / 2)]])


def test_linear_model_error_is_second_order_with_contacts_held():
    """Two identical worlds pressed into a frictionless wall; at the last step one handle goes
    a little further and turns a little: the first's model predicts the second's wrench with an
    error that falls as the square of the displacement (the rotation is the nonlinear part).
    Frictionless because with sliding friction the turn of the sliding direction is a small
    first-order term the model leaves out (the next test bounds it; docs/haptics.md)."""
    def pressed(dx: np.ndarray, dtheta: np.ndarray):
        sc = hand_scene()
        sc.data["hand"]["friction"] = 0.0
        rig = Rig(sc, wall_gap=0.001, wall_friction=0.0)
        for k in range(1, 16):
            last = k == 15
            target = rig.com - [0.006 * k / 15, 0, 0] + (dx if last else 0.0)
            q = quat_from_rotation_vector(dtheta) if last else [0.0, 0.0, 0.0, 1.0]
            rig.world.set_device(rig.hand, target, q, enabled=2)
            rig.world.step()
        return rig.world.coupling_model(rig.hand)

    w0, stiffness, held = pressed(np.zeros(3), np.zeros(3))
    assert held > 0
    errors = []
    for delta in (4e-3, 2e-3, 1e-3):
        dx, dtheta = np.array([-0.01, 0.003, 0.0]) * delta, np.array([0.3, -1.0, 0.5]) * delta
        w1, _, _ = pressed(dx, dtheta)
        errors.append(np.linalg.norm(w1 - (w0 + stiffness @ np.concatenate([dx, dtheta]))))
    assert np.linalg.norm(w1 - w0) > 5 * errors[-1]  # at the smallest step the model explains the change
    assert 3.5 < errors[0] / errors[1] < 4.5 and 3.5 < errors[1] / errors[2] < 4.5


def test_linear_model_follows_sliding_friction():
    """Pressed into a wall with friction 0.5, the fingertips slide: the model's friction
    follows the normal impulse, so it predicts the force change within 2% (holding the normal
    rows alone missed it by 10%, the friction coefficient's share)."""
    def pressed(dx: np.ndarray):
        rig = Rig(hand_scene(), wall_gap=0.001, wall_friction=0.5)
        for k in range(1, 16):
            target = rig.com - [0.006 * k / 15, 0, 0] + (dx if k == 15 else 0.0)
            rig.world.set_device(rig.hand, target, [0.0, 0.0, 0.0, 1.0], enabled=2)
            rig.world.step()
        return rig.world.coupling_model(rig.hand)

    w0, stiffness, held = pressed(np.zeros(3))
    assert held > 0
    dx = np.array([-5e-5, 1.5e-5, 0.0])
    w1, _, _ = pressed(dx)
    change = (w1 - w0)[:3]
    error = (w1 - (w0 + stiffness @ np.concatenate([dx, np.zeros(3)])))[:3]
    assert np.linalg.norm(error) < 0.02 * np.linalg.norm(change)


def test_offline_sessions_repeat_bit_for_bit():
    def once():
        rig = Rig(hand_scene(gravity=(0.0, 0.0, -9.81)), wall_gap=0.002)
        rig.simulated_user([0.0, 1.0], [[0, 0, 0], [-0.01, 0, 0]])
        return rig.run(1.0)
    a, b = once(), once()
    for key in ("force", "proxy_position", "device_position"):
        assert np.array_equal(a[key], b[key])


@pytest.mark.parametrize("kind", ["simulated", "playback"])
def test_device_that_disconnects_stops_with_a_message_and_keeps_what_was_done(kind):
    rig = Rig(hand_scene(gravity=(0.0, 0.0, -9.81)))
    if kind == "simulated":
        rig.session.device_simulated([0.0], rig.com[None, :], fail_at=0.5)
    else:
        rig.session.device_playback([0.0, 1.0], [rig.com, rig.com + [0.01, 0, 0]], fail_at=0.5)
    with pytest.raises(native.InvalidInput, match="disconnect"):
        rig.run(2.0)
    log = native_session.log_arrays(rig.session.read_log())
    assert log["t"][-1] < 0.5 <= log["t"][-1] + 2e-3  # every step before the failure is logged
    status = rig.session.status()
    assert status["failed"] and "disconnect" in status["message"]
    x, _ = rig.world.nodes(rig.hand)  # the last visual state is still there
    assert np.all(np.isfinite(x))


@pytest.mark.parametrize("dt", [1 / 30, 1 / 60, 0.025])
def test_offline_haptic_steps_land_on_exact_multiples_of_the_period(dt):
    """The offline haptic clock is the one a 1 kHz device would see, whatever the frame rate:
    step n at n / rate exactly (the remainder of a frame carried to the next), so every period
    is 1 ms, and by the end of frame k the steps up to (k + 1) dt have run."""
    sc = hand_scene()
    sc.data["dt"] = dt
    rig = Rig(sc)
    rig.simulated_user([0.0, 0.5], [[0, 0, 0], [0.01, 0, 0]])
    rate = sc.data["haptics"]["rate"]
    counts = []
    for _ in range(int(round(0.5 / dt))):
        rig.session.run_offline(1)
        counts.append(rig.session.status()["haptic_steps"])
    log = native_session.log_arrays(rig.session.read_log())
    n = np.arange(1, len(log["t"]) + 1)
    assert np.abs(log["t"] - n / rate).max() < 1e-12
    assert np.abs(np.diff(log["t"]) - 1 / rate).max() < 1e-12
    assert np.abs(log["period"] - 1 / rate).max() < 1e-12
    frames = np.arange(1, len(counts) + 1)
    assert np.array_equal(counts, np.floor(frames * dt * rate + 1e-6).astype(int))


def jump_scene(jump: float, frames: int, **haptics) -> scenes.Scene:
    """The device trajectory jumps `jump` m along x in 0.1 ms at t = 0.2 s (a teleport, a typo)."""
    sc = hand_scene(gravity=(0.0, 0.0, -9.81), **haptics)
    sc.data["device"]["trajectory"] = [{"t": 0.0, "position": [0, 0, 0]}, {"t": 0.2, "position": [0, 0, 0]},
                                       {"t": 0.2001, "position": [jump, 0, 0]}]
    sc.data["frames"] = frames
    return sc


def test_a_half_metre_jump_of_the_simulated_user_settles_whole_within_max_force():
    """The simulated arm follows a 0.5 m jump of its target as a person's arm would (at most
    3 m/s), so the hand is carried over without tearing: no tet inverted from 1 s after the jump,
    the felt force within max_force, and no warning."""
    sc = jump_scene(0.5, 45, max_force=20.0)
    result = simulate.run(sc)
    log = result["haptic"]
    felt = np.linalg.norm(log["force"], axis=1)
    assert felt.max() <= 20.0 * (1 + 1e-12)
    speed = np.linalg.norm(np.diff(log["device_position"], axis=0), axis=1) / np.diff(log["t"])
    assert speed.max() <= 3.0 * (1 + 1e-9)
    assert log["device_position"][-1, 0] - log["device_position"][0, 0] == pytest.approx(0.5, abs=0.01)  # it got there
    settled = result["time"] >= 1.2
    assert result["inverted_tets"][settled].max() == 0
    assert int(result["torn_frame"]) == -1 and int(result["strayed_frame"]) == -1
    assert "WARNING" not in simulate.summary(result)


def test_a_fifty_metre_jump_of_a_playback_device_is_reported_with_its_frame(tmp_path):
    """A recorded trajectory is replayed as it is: a 50 m jump in it yanks the proxy, and with it
    the handle, away from the flesh. The result file and the summary say so, with the frame."""
    sc = jump_scene(0.0, 14)
    sc.data["hand"]["self_collision"] = False  # the torn hand's self-contacts only cost time here
    com = np.array(scenes.build_model(sc).info()["handle_com"])
    path = tmp_path / "jump.csv"
    rows = [(0.0, *com), (0.2, *com), (0.2001, com[0] + 50.0, com[1], com[2])]
    path.write_text("t,x,y,z\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    sc.data["haptics"]["device"] = f"playback:{path}"
    result = simulate.run(sc)
    jump_frame = int(round(0.2 / sc.dt))
    torn, strayed = int(result["torn_frame"]), int(result["strayed_frame"])
    assert jump_frame <= strayed <= jump_frame + 1 and jump_frame <= torn <= jump_frame + 2
    assert result["inverted_tets"][torn] > 0
    text = simulate.summary(result)
    assert f"tore at frame {torn}" in text and f"strayed from the handle at frame {strayed}" in text
    stored = np.load(simulate.write(result, tmp_path / "r.npz"))
    assert int(stored["strayed_frame"]) == strayed and len(stored["warnings"]) == 2


def test_a_coupling_stiffer_than_the_haptic_loop_is_tested_at_is_refused_with_the_fix():
    k_max = params.by_json("coupling.stiffness").soft_max  # HH_HAPTIC_MAX_COUPLING_STIFFNESS
    assert k_max == 3e4  # docs/haptics.md: the stiffest coupling the wall test holds stable
    native_session.check_params(coupling_stiffness=k_max)
    with pytest.raises(native.InvalidInput, match=r"coupling.stiffness = 30300.* at most 3e4 N/m, the stiffest"):
        native_session.check_params(coupling_stiffness=1.01 * k_max)


def test_a_virtual_coupling_that_is_not_passive_is_refused_with_the_fix():
    """Colgate: sampled at T = 1 ms, a 2000 N/m coupling needs at least K T / 2 = 1 N s/m of damping."""
    rig_scene = hand_scene()
    world, hand, _, _, _ = simulate.build_world(rig_scene)
    with pytest.raises(native.InvalidInput, match=r"not passive at 1000 Hz.*at least 1 N s/m.*at most 1000 N/m"):
        native_session.NativeSession(world, hand, coupling_stiffness=2000.0, coupling_damping=0.5)
    with pytest.raises(native.InvalidInput, match=r"angular damping 0 .*at least 0.01 N m s/rad"):
        native_session.NativeSession(world, hand, coupling_angular_stiffness=20.0, coupling_angular_damping=0.0)
    native_session.NativeSession(world, hand, coupling_stiffness=2000.0, coupling_damping=1.0).close()  # on the bound


def test_a_scene_whose_coupling_is_not_passive_is_refused_when_it_loads():
    """The passivity bound is part of the session's checks, so a scene file is refused when it is
    read, before any world is built: at 500 Hz (T = 2 ms) a 3000 N/m coupling needs K T / 2 =
    3 N s/m of damping."""
    data = {"format": "haptic_hand.scene/1", "haptics": {"enabled": True, "rate": 500.0},
            "coupling": {"stiffness": 3000.0, "damping": 2.0}}
    with pytest.raises(scenes.SceneError, match=r"not passive at 500 Hz.*at least 3 N s/m"):
        scenes.from_dict(data)
    data["coupling"]["damping"] = 3.0  # on the bound
    scenes.from_dict(data)


def test_simulate_writes_the_haptic_log(tmp_path):
    sc = hand_scene(gravity=(0.0, 0.0, -9.81))
    sc.data["frames"] = 12
    result = simulate.run(sc)
    log = result["haptic"]
    assert len(log["t"]) == 400  # 12 frames of 1/30 s at 1 kHz
    assert np.allclose(np.diff(log["t"]), 1e-3)
    path = simulate.write(result, tmp_path / "r.npz")
    stored = np.load(path)
    assert np.array_equal(stored["haptic_force"], log["force"])


def test_live_session_runs_on_its_own_threads():
    sc = hand_scene(gravity=(0.0, 0.0, -9.81))
    live = session.LiveSession(sc, device="simulated")
    live.start()
    frames, deadline = [], __import__("time").monotonic() + 1.0
    while __import__("time").monotonic() < deadline:
        f = live.poll()
        if f is not None:
            frames.append(f)
        __import__("time").sleep(0.01)
    assert live.running
    live.stop()
    assert live.error is None
    log = live.haptic_log()
    assert 500 < len(log["t"]) < 1500  # about 1 kHz for 1 s (loose: CI machines are busy)
    assert len(frames) >= 5 and frames[-1].time > frames[0].time
    n = len(sc.surface_vertices)
    assert frames[-1].surfaces["hand"].shape == (n, 3)


def test_live_frames_carry_the_poses_of_moving_bodies():
    sc = hand_scene()
    sc.data["bodies"] = [{"name": "pusher", "type": "kinematic", "mesh": "box", "size": [0.02, 0.02, 0.02],
                          "position": [0.3, 0.0, 0.0],
                          "trajectory": [{"t": 0.0, "position": [0, 0, 0]}, {"t": 10.0, "position": [1.0, 0, 0]}]}]
    sc = scenes.from_dict(sc.data, sc.base_dir)
    live = session.LiveSession(sc, device="simulated")
    start = live.world.pose(live.body_names.index("pusher"))[0]  # before the loops own the world
    live.start()
    import time
    deadline, last = time.monotonic() + 1.0, None
    while time.monotonic() < deadline:
        f = live.poll()
        if f is not None:
            last = f
        time.sleep(0.01)
    live.stop()
    assert last is not None and last.time > 0
    # the script moves the box 0.1 m/s along x from where it started (frame 0 is t = 0)
    assert last.poses["pusher"][0] - start[0] == pytest.approx(0.1 * last.time, abs=1e-9)


def test_closing_a_session_never_started_leaves_the_live_one_in_charge_of_its_world():
    """Two sessions on one world: B, created before A starts and never started, is closed while
    A runs. The world stays A's: stepping it from here is refused until A stops."""
    rig = Rig(hand_scene(gravity=(0.0, 0.0, -9.81)))
    rig.simulated_user([0.0], [[0, 0, 0]])
    other = session.create(rig.world, rig.hand, rig.sc)
    other.device_simulated([0.0], rig.com[None, :])
    rig.session.start()
    try:
        with pytest.raises(native.InvalidInput, match="another live session"):
            other.start()
        other.close()
        with pytest.raises(native.InvalidInput, match="live haptic session is stepping this world"):
            rig.world.step()
        assert rig.session.status()["running"]
    finally:
        rig.session.stop()
    rig.world.step()  # A gave the world back


def test_an_external_device_that_never_connects_holds_the_hand_then_stops_with_a_message():
    """Offline, virtual time: the host never pushes a pose. Until the timeout the device stands
    where the handle is (no pull toward the world's origin); then the run ends with the fix."""
    rig = Rig(hand_scene())
    rig.session.device_external(timeout=0.3)
    with pytest.raises(native.InvalidInput, match=r"no pose within 0\.3 s.*external_timeout"):
        rig.run(1.0)
    log = native_session.log_arrays(rig.session.read_log())
    assert 0.3 - 2e-3 <= log["t"][-1] <= 0.3 + 2e-3
    assert np.abs(log["device_position"] - rig.com).max() < 1e-12
    # no gravity, the hand at rest and its device on the handle: nothing to feel
    assert np.abs(log["force"]).max() < 1e-6


def test_a_live_external_device_that_never_connects_ends_the_session_with_a_message():
    import time
    sc = hand_scene()
    sc.data["haptics"]["external_timeout"] = 0.2
    live = session.LiveSession(scenes.from_dict(sc.data, sc.base_dir), device="external")
    live.start()
    deadline = time.monotonic() + 3.0
    while live.running and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not live.running
    live.stop()
    assert live.error is not None and "no pose within 0.2 s" in live.error
