"""The simulated Panda executes a pick-and-place in PyBullet."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from neoedit.errors import NeoError
from neoedit.geometry import motion_about
from neoedit.sim.execute import (
    ExecuteConfig,
    PandaArm,
    execute_move,
    placement_error,
    reach_error,
    reachable_first,
)
from neoedit.sim.spec import ActionSpec, ObjectSpec, SceneSpec
from neoedit.sim.world import SimWorld


def _world(position=(-0.12, 0.0, 0.005)) -> SimWorld:
    spec = SceneSpec(
        name="pick",
        objects=[ObjectSpec("cube", "pybullet_data:cube_small.urdf", position_m=position)],
        actions=[ActionSpec("move", "cube", translate_m=(0.05, 0.1, 0.0), yaw_deg=30.0)],
    )
    return SimWorld(spec)


def _top_down(world: SimWorld) -> dict:
    """A top-down grasp across the cube's x faces (what the planner returns for a cube)."""
    return _top_down_of(world, "cube")


def _top_down_of(world: SimWorld, name: str) -> dict:
    box = world.object_box(name)
    rot_box = box.rotation
    closing, approach = rot_box[:, 0], np.array([0.0, 0.0, -1.0])
    finger = np.cross(approach, closing)
    return {
        "position_m": list(box.center_m),
        "rotation": np.stack([closing, finger, approach], -1).tolist(),
        "width_m": box.size_m[0],
    }


def test_the_arm_lifts_a_cube_and_places_it_where_the_move_says():
    with _world() as world:
        centre = np.asarray(world.object_box("cube").center_m)
        transform = motion_about(centre, np.array([0.05, 0.1, 0.0]), 30.0)
        ex = execute_move(world, "cube", _top_down(world), transform, ExecuteConfig())
        assert ex.success, ex.cause
        err = placement_error(ex.transform, transform, world, "cube")
        assert err["position_m"] < 0.01 and err["yaw_deg"] < 5.0


def test_an_unreachable_grasp_is_reported_with_its_cause():
    with _world(position=(0.55, 0.0, 0.005)) as world:  # ~1.2 m from the Panda's base
        centre = np.asarray(world.object_box("cube").center_m)
        transform = motion_about(centre, np.array([0.0, 0.05, 0.0]), 0.0)
        ex = execute_move(world, "cube", _top_down(world), transform, ExecuteConfig())
        assert not ex.success and ex.stage == "reach" and "cannot reach" in ex.cause


def test_an_approach_stopped_by_the_object_says_so():
    """Fingers opened narrower than the cube land on its top: the motion stops short, and
    the cause names what stopped it rather than the arm's reach."""
    with _world() as world:
        centre = np.asarray(world.object_box("cube").center_m)
        transform = motion_about(centre, np.array([0.05, 0.1, 0.0]), 30.0)
        grasp = {**_top_down(world), "opening_m": 0.01, "width_m": 0.005}
        ex = execute_move(world, "cube", grasp, transform, ExecuteConfig())
        assert not ex.success and ex.stage == "approach", ex.cause
        assert "stopped" in ex.cause and "against cube" in ex.cause, ex.cause


def test_a_robot_without_a_gripper_is_refused():
    from neoedit.sim.catalog import SETUPS

    spec = SceneSpec(
        name="kuka",
        setup=SETUPS["kuka_checker"],
        objects=[ObjectSpec("cube", "pybullet_data:cube_small.urdf")],
    )
    with SimWorld(spec) as world, pytest.raises(NeoError, match="no parallel gripper"):
        execute_move(world, "cube", _top_down(world), np.eye(4), ExecuteConfig())


def test_the_reach_check_predicts_the_motion_and_leaves_the_world_as_it_was():
    with _world() as world:
        centre = np.asarray(world.object_box("cube").center_m)
        transform = motion_about(centre, np.array([0.05, 0.1, 0.0]), 30.0)
        before = world.object_pose("cube")
        joints = PandaArm(world, ExecuteConfig()).joints()
        err, _ = reach_error(world, _top_down(world), transform, ExecuteConfig())
        assert err < ExecuteConfig().reach_tolerance_m
        far = motion_about(centre, np.array([0.9, 0.0, 0.0]), 0.0)  # carried 1.4 m from the base
        err, stage = reach_error(world, _top_down(world), far, ExecuteConfig())
        assert err > 0.1 and stage in ("carry", "place", "retreat")
        np.testing.assert_array_equal(world.object_pose("cube"), before)
        np.testing.assert_allclose(PandaArm(world, ExecuteConfig()).joints(), joints, atol=1e-9)
        ex = execute_move(world, "cube", _top_down(world), transform, ExecuteConfig())
        assert ex.success, ex.cause  # the arm was put back home: the motion still works


def test_solving_a_waypoint_refines_the_inverse_kinematics_and_keeps_the_arm_moving():
    """A motion solves each waypoint as the reach check does (inverse kinematics refined
    from its own clipped solution), without disturbing the arm: its joint positions and
    velocities are what they were."""
    import pybullet as pb

    with _world() as world:
        arm = PandaArm(world, ExecuteConfig())
        for k, j in enumerate(arm.arm):  # an arm in motion
            pb.resetJointState(arm.robot, j, arm.home[k], 0.1 * (k + 1), physicsClientId=arm.c)
        states = pb.getJointStates(arm.robot, arm.arm, physicsClientId=arm.c)

        def moving() -> list[tuple[float, float]]:
            got = pb.getJointStates(arm.robot, arm.arm, physicsClientId=arm.c)
            return [(st[0], st[1]) for st in got]

        before = moving()

        def error(q: np.ndarray, pos: np.ndarray) -> float:
            arm.set_joints(q)
            return float(np.linalg.norm(arm.ee_pose()[0] - pos))

        rot = np.diag([1.0, -1.0, -1.0])  # pointing down
        # near the base and low, one clipped solution from home misses by centimetres
        hard = np.array([-0.4, 0.3, 0.02])
        for pos in (np.array([-0.1, 0.1, 0.1]), np.array([0.2, -0.15, 0.05]), hard):
            single, solved = arm.ik(pos, rot), arm.solve(pos, rot)
            assert moving() == before
            assert np.all(solved >= arm.limits[:, 0]) and np.all(solved <= arm.limits[:, 1])
            e_single, e_solved = error(single, pos), error(solved, pos)
            assert e_solved <= e_single + 1e-4
            if pos is hard:
                assert e_single > 0.01 and e_solved < 0.002, (e_single, e_solved)
            for j, st in zip(arm.arm, states, strict=True):
                pb.resetJointState(arm.robot, j, st[0], st[1], physicsClientId=arm.c)


def test_sim_execute_runs_the_first_grasp_the_arm_reaches(tmp_path, capsys):
    import json

    from conftest import TINY_SCAN

    from neoedit.cli import main
    from neoedit.sim.run import simulate_scene

    with _world() as world:
        good = _top_down(world)
        spec = world.spec
    simulate_scene(dataclasses.replace(spec, scan=TINY_SCAN), tmp_path / "scene")
    far = {**good, "position_m": [0.75, 0.3, 0.02]}  # 1.4 m from the Panda's base
    order = reachable_first(tmp_path / "scene", 1, [far, good], ExecuteConfig())
    assert [r.grasp for r in order] == [1, 0] and order[1].error_m > 0.1
    (tmp_path / "grasps.json").write_text(json.dumps([far, good]))
    args = ["sim", "execute", str(tmp_path / "scene"), "--action", "1"]
    args += ["--grasp", str(tmp_path / "grasps.json"), "--out", str(tmp_path / "run")]
    assert main(args) == 0
    assert "executing grasp 2 of 2" in capsys.readouterr().out
    record = json.loads((tmp_path / "run" / "execution.json").read_text())
    assert record["success"] and record["placement_error"]["position_m"] < 0.01


def test_the_place_stops_where_the_object_meets_its_support():
    """A target 2 cm inside the table: the guarded descent stops when the cube touches the
    table and lets go there, instead of pressing it into the table until the arm gives up."""
    with _world() as world:
        centre = np.asarray(world.object_box("cube").center_m)
        transform = motion_about(centre, np.array([0.05, 0.1, -0.02]), 0.0)
        ex = execute_move(world, "cube", _top_down(world), transform, ExecuteConfig())
        assert ex.success, ex.cause
        box = world.object_box("cube")
        assert abs(box.center_m[2] - centre[2]) < 0.003  # resting on the table, upright
        assert np.linalg.norm(np.subtract(box.center_m[:2], centre[:2] + [0.05, 0.1])) < 0.01


def test_a_support_met_high_above_the_target_fails_the_place_instead_of_dropping():
    """The target is where another cube stands: coming down, the held cube meets that
    cube's top 5 cm above its target. The place stops there and says so; it does not let
    go and call the drop a placement."""
    spec = SceneSpec(
        name="blocked",
        objects=[
            ObjectSpec("cube", "pybullet_data:cube_small.urdf", position_m=(-0.12, 0.0, 0.005)),
            ObjectSpec("block", "pybullet_data:cube_small.urdf", position_m=(-0.05, 0.12, 0.005)),
        ],
        actions=[],
    )
    with SimWorld(spec) as world:
        here = np.asarray(world.object_box("cube").center_m)
        there = np.asarray(world.object_box("block").center_m)
        transform = motion_about(here, there - here, 0.0)
        ex = execute_move(world, "cube", _top_down(world), transform, ExecuteConfig())
        assert not ex.success and ex.stage == "place", ex.cause
        assert "met block" in ex.cause and "above its target" in ex.cause, ex.cause
