"""Scene values that hold between numbers are checked once, by the library, and the scene loader
passes its message on with the field's name: a trajectory's times and quaternions, a box body's
cells. The device names a scene takes are engine.devices' one list."""

import pytest

from haptic_hand.engine import devices, params
from haptic_hand.engine import scene as scenes


def scene(**fields) -> dict:
    return {"format": scenes.FORMAT, **fields}


def poses(*times, quaternion=(0, 0, 0, 1)) -> list:
    return [{"t": t, "position": [0, 0, 0], "quaternion": list(quaternion)} for t in times]


@pytest.mark.parametrize("times, words", [
    ((0, 1, 0.5), "pose 2 has t = 0.5 s after 1 s"),
    ((0, 0.2, 0.2), "pose 2 has t = 0.2 s after 0.2 s"),
])
def test_device_trajectory_times_must_increase_strictly(times, words):
    with pytest.raises(scenes.SceneError) as e:
        scenes.from_dict(scene(device={"trajectory": poses(*times)}))
    assert str(e.value) == (f"device.trajectory {words}: times must increase strictly; give each pose a later time "
                            "than the one before")


def test_a_zero_quaternion_is_refused_with_the_fix():
    points = poses(0) + poses(1, quaternion=(0, 0, 0, 0))
    with pytest.raises(scenes.SceneError, match=r"^device\.trajectory pose 1 has a zero quaternion: use \(x, y, z, s\) "
                                                r"with s = 1 for no rotation$"):
        scenes.from_dict(scene(device={"trajectory": points}))


def test_quaternions_come_back_unit_length():
    points = poses(0, quaternion=(0, 0, 0, 2)) + poses(1, quaternion=(0, 0, 3, 4))
    times, _, quats = scenes.timed_poses(points, "device.trajectory")
    assert times.tolist() == [0, 1] and quats.tolist() == [[0, 0, 0, 1], [0, 0, 0.6, 0.8]]


def test_a_kinematic_script_is_checked_alike_naming_its_body():
    body = {"name": "k", "type": "kinematic", "mesh": "box", "trajectory": poses(0, 0)}
    with pytest.raises(scenes.SceneError, match=r"^body 'k': trajectory pose 1 has t = 0 s after 0 s: times must "
                                                r"increase strictly"):
        scenes.from_dict(scene(bodies=[body]))


def box(cells) -> dict:
    return {"name": "b", "type": "soft", "mesh": "box", "cells": cells}


def test_a_box_body_of_more_tets_than_a_step_can_take_is_refused_before_it_is_meshed():
    # 6 tets a cell: 34 x 34 x 28 cells make 194,208 tets, 34 x 34 x 29 make 201,144 (over 200,000)
    scenes.from_dict(scene(bodies=[box([34, 34, 28])]))
    with pytest.raises(scenes.SceneError) as e:
        scenes.from_dict(scene(bodies=[box([34, 34, 29])]))
    assert str(e.value) == ("body 'b': cells [34, 34, 29] make 201,144 tets, over 200,000: use fewer cells (a few "
                            "per centimetre)")


def test_the_scene_takes_exactly_the_devices_engine_devices_lists():
    for name in devices.NAMES:
        assert scenes.from_dict(scene(haptics={"device": name})).data["haptics"]["device"] == name
    with pytest.raises(scenes.SceneError, match="haptics.device 'phantom' is unknown: use " + ", ".join(devices.NAMES)):
        scenes.from_dict(scene(haptics={"device": "phantom"}))
    described = params.by_json("haptics.device").description
    assert all(name in described for name in devices.NAMES)
    assert set(devices.MENU_NAMES.values()) == set(devices.NAMES)
