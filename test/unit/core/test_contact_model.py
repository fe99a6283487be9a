# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The contact estimator, the rendered wall and the choice between them (no ROS)."""
from kraft_master_driver.core.contact_model import (
    ContactEstimator, ContactModel, MODEL_FIELDS, NO_CONTACT)
from kraft_master_driver.core.contact_rendering import (
    ContactRenderer, renderable_stiffness, RendererSettings)
from kraft_master_driver.core.force_mode import ForceMode, ModeSelector, ModeSettings
import numpy as np
import pytest

TABLE = 0.4  # m, z of a table top
STIFFNESS, DAMPING = 3000.0, 50.0


def press(estimator, depths, start=0.0, dt=0.002, table=TABLE):
    """Feed the estimator a tool at each depth past the table, its spring-damper's force."""
    previous = None
    for step, depth in enumerate(depths):
        rate = 0.0 if previous is None else (depth - previous) / dt
        force = max(0.0, STIFFNESS * depth + DAMPING * rate) if depth > 0.0 else 0.0
        estimator.update(np.array([0.3, 0.0, table - depth]), np.array([0.0, 0.0, force]),
                         start + step * dt)
        previous = depth
    return start + len(depths) * dt


def test_the_estimator_finds_the_plane_its_stiffness_and_damping():
    estimator = ContactEstimator()
    assert estimator.model() == NO_CONTACT
    depths = [0.002 - 0.00005 * i for i in range(40)]  # from 2 mm above the top
    depths += [0.004 * np.sin(0.02 * i) ** 2 for i in range(1, 1000)]  # presses in and out
    press(estimator, depths)
    model = estimator.model()
    assert model.normal == pytest.approx((0.0, 0.0, 1.0))
    assert model.point[2] == pytest.approx(TABLE, abs=2e-4)  # the last reading before
    assert model.stiffness == pytest.approx(STIFFNESS, rel=0.05)
    assert model.damping == pytest.approx(DAMPING, rel=0.3)
    assert model.confidence > 0.5


def test_free_motion_past_the_surface_moves_it_and_a_new_touch_finds_it_again():
    estimator = ContactEstimator()
    end = press(estimator, [0.001 - 0.0001 * i for i in range(10)]
                + [0.003 * np.sin(0.01 * i) for i in range(300)])
    # The table drops 10 mm: the tool goes 12 mm down without a force.
    for step in range(60):
        estimator.update(np.array([0.3, 0.0, TABLE - 0.0002 * step]), np.zeros(3),
                         end + step * 0.002)
    assert estimator.model().point[2] < TABLE - 0.01
    # And touches it where it now is.
    press(estimator, [0.0005 - 0.00005 * i for i in range(20)]
          + [0.003 * np.sin(0.01 * i) for i in range(300)], start=end + 1.0,
          table=TABLE - 0.01)
    assert estimator.model().point[2] == pytest.approx(TABLE - 0.01, abs=2e-4)


def test_a_model_crosses_as_named_values_and_bad_ones_are_refused_in_one_line():
    model = ContactModel((0.1, 0.2, 0.3), (0.0, 0.0, 1.0), 500.0, 2.0, 0.9, True)
    assert ContactModel.from_values(MODEL_FIELDS, model.values()) == model
    with pytest.raises(ValueError, match='not finite'):
        ContactModel.from_values(MODEL_FIELDS, [float('nan')] + model.values()[1:])
    with pytest.raises(ValueError, match='not 1'):
        ContactModel.from_values(MODEL_FIELDS, [0, 0, 0, 0, 0, 2.0, 500, 2, 0.9, 1])
    with pytest.raises(ValueError, match='expected the fields'):
        ContactModel.from_values(MODEL_FIELDS[:3], [0.0, 0.0, 0.0])


def test_the_renderable_wall_follows_colgate_and_schenkel():
    assert renderable_stiffness(1000.0, 0.4) == pytest.approx(800.0)
    assert renderable_stiffness(2000.0, 0.4) == pytest.approx(1600.0)
    assert renderable_stiffness(1000.0, 0.4, damping=0.1) == pytest.approx(600.0)


WALL = ContactModel((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 400.0, 0.0, 1.0, True)


def test_the_wall_pushes_out_of_the_surface_and_not_in_free_space():
    renderer = ContactRenderer()
    renderer.take(WALL, 0)
    assert renderer.force((0.0, 0.0, 0.01), (0.0, 0.0, 0.0), 1_000_000) == (0.0, 0.0, 0.0)
    for step in range(2, 12):  # into the surface, 1 mm a step
        renderer.applied(1.0)
        force = renderer.force((0.0, 0.0, -0.001 * (step - 1)), (0.0, 0.0, -1.0),
                               step * 1_000_000)
    assert force[2] == pytest.approx(400.0 * 0.010)
    assert renderer.balance > 0.0


def test_a_surface_found_past_the_hand_starts_at_the_hand_and_its_force_grows_smoothly():
    settings = RendererSettings()
    renderer = ContactRenderer(settings)
    renderer.take(WALL, 0)
    forces = []
    for step in range(1, 400):  # the hand holds 10 mm past the model's surface
        renderer.applied(1.0)
        forces.append(renderer.force((0.0, 0.0, -0.01), (0.0, 0.0, 0.0), step * 1_000_000)[2])
    most = WALL.stiffness * settings.approach_speed / settings.rate_hz + 1e-9
    assert forces[0] <= most
    assert np.diff(forces).max() <= most
    assert forces[-1] == pytest.approx(4.0)  # at its place, as the hand did not move


def test_the_wall_fades_rather_than_give_back_more_than_it_took():
    renderer = ContactRenderer(RendererSettings(update_energy=0.0))
    renderer.take(WALL, 0)
    position = -0.01
    for step in range(1, 300):  # the surface at the hand; then the hand is pulled out fast
        renderer.applied(1.0)
        renderer.force((0.0, 0.0, position), (0.0, 0.0, 0.2), step * 1_000_000)
        position += 0.0002 if step > 100 else 0.0
    assert renderer.energy_out <= renderer.energy_in + 1e-9


def test_a_model_not_refreshed_within_its_timeout_is_gone():
    renderer = ContactRenderer(RendererSettings(model_timeout=0.5))
    renderer.take(WALL, 0)
    renderer.force((0.0, 0.0, 0.001), (0.0, 0.0, 0.0), 1_000_000)
    assert renderer.force((0.0, 0.0, -0.001), (0.0, 0.0, 0.0), 600_000_000) == (0.0, 0.0, 0.0)


def test_auto_chooses_the_model_above_its_round_trip_and_direct_again_below_with_a_ramp():
    selector = ModeSelector(ModeSettings(ForceMode.AUTO, model_above=0.05, direct_below=0.03,
                                         switch_time=0.5))
    selector.delay(0.005, 0)
    assert selector.weight(0) == 0.0
    selector.delay(0.04, 1_000_000)  # 80 ms round trip
    assert selector.model_chosen
    assert selector.weight(250_000_000) == pytest.approx(0.5)
    assert selector.weight(600_000_000) == 1.0
    selector.delay(0.02, 700_000_000)  # 40 ms: inside the hysteresis, still the model
    assert selector.model_chosen
    selector.delay(0.005, 10_000_000_000)  # the peak has decayed: direct again
    assert not selector.model_chosen
    with pytest.raises(ValueError, match='direct_below'):
        ModeSelector(ModeSettings(ForceMode.AUTO, model_above=0.02, direct_below=0.03))


def test_with_passivity_on_auto_renders_the_model_at_any_round_trip_until_it_is_off():
    settings = ModeSettings(ForceMode.AUTO, model_above=0.05, direct_below=0.03, switch_time=0.1)
    selector = ModeSelector(settings, passivity=True)
    assert selector.weight(0) == 1.0  # from the start, before any delay is measured
    selector.delay(0.0, 1_000_000)  # 0 ms round trip
    assert selector.model_chosen and selector.weight(2_000_000) == 1.0
    selector.passivity = False  # at run time: direct again below direct_below
    selector.delay(0.0, 3_000_000)
    assert not selector.model_chosen
    assert selector.weight(52_000_000) == pytest.approx(0.5)  # blended, not a step
    # The other modes do not change with it.
    for mode, chosen in ((ForceMode.DIRECT, False), (ForceMode.MODEL, True)):
        fixed = ModeSelector(ModeSettings(mode), passivity=True)
        fixed.delay(0.0, 0)
        assert fixed.model_chosen is chosen


def test_the_bridge_sends_the_model_in_the_masters_frame_on_change_and_as_a_heartbeat():
    from kraft_master_driver.core.teleoperation_contact import (
        ContactSharing, HEARTBEAT, Registration)
    from kraft_master_driver.core.teleoperation_motion import Pose
    from kraft_master_driver.core.teleoperation_settings import Settings
    sharing = ContactSharing(Settings(scale=2.0, force_scale=0.5, arm_stiffness=1000.0))
    press(sharing.estimator, [0.001 - 0.0001 * i for i in range(10)]
          + [0.003 * np.sin(0.01 * i) for i in range(300)])
    master = Pose(np.array([0.1, 0.0, 0.2]), np.eye(3))
    arm = Pose(np.array([0.3, 0.0, TABLE + 0.05]), np.eye(3))
    registration = Registration(master, arm, np.eye(3))
    model = sharing.to_send(registration, 10.0)
    # The table 50 mm below the arm is 25 mm below the master at scale 2.
    assert model.point[2] == pytest.approx(0.2 - 0.025, abs=1e-4)
    series = STIFFNESS * 1000.0 / (STIFFNESS + 1000.0)
    assert model.stiffness == pytest.approx(series * 2.0 * 0.5, rel=0.05)
    assert sharing.to_send(registration, 10.0 + HEARTBEAT / 2) is None
    assert sharing.to_send(registration, 10.0 + 1.5 * HEARTBEAT) == model
    # Not following: a model of no stiffness, the master renders no wall.
    assert sharing.to_send(None, 10.0 + 1.5 * HEARTBEAT).stiffness == 0.0


def test_with_a_tolerance_the_arm_yields_where_it_presses_harder_than_the_model():
    from kraft_master_driver.core.teleoperation_contact import ContactSharing, Registration
    from kraft_master_driver.core.teleoperation_motion import Pose
    from kraft_master_driver.core.teleoperation_settings import Settings
    sharing = ContactSharing(Settings(model_tolerance=2.0))
    press(sharing.estimator, [0.001 - 0.0001 * i for i in range(10)]
          + [0.003 * np.sin(0.01 * i) for i in range(300)])
    pose = Pose(np.zeros(3), np.eye(3))
    sharing.to_send(Registration(pose, pose, np.eye(3)), 10.0)
    command = np.array([0.3, 0.0, TABLE - 0.002])
    at_two_mm = STIFFNESS * 0.002
    sharing.reading(command, np.array([0.0, 0.0, at_two_mm + 1.0]), Pose(command, np.eye(3)), 10.1)
    assert sharing.floor is None  # within the tolerance
    sharing.reading(command, np.array([0.0, 0.0, at_two_mm + 5.0]), Pose(command, np.eye(3)), 10.2)
    normal, least = sharing.floor
    assert normal == pytest.approx([0.0, 0.0, 1.0], abs=1e-3)
    assert least == pytest.approx(TABLE - 0.002, abs=1e-4)
    sharing.reading(command, np.array([0.0, 0.0, at_two_mm]), Pose(command, np.eye(3)), 10.3)
    assert sharing.floor is None


def test_the_force_blends_direct_and_model_and_takes_the_model_alone_without_a_wrench():
    from kraft_master_driver.core.force_reflection import ACTIVE, ForceReflection
    from kraft_master_driver.core.wrench_admission import BASE_FRAME, WrenchInput
    reflection = ForceReflection(enabled=True)
    rotation = np.eye(3).tolist()
    jacobian = np.eye(6).tolist()
    reflection.hold(WrenchInput((0.0, 0.0, 0.5, 0.0, 0.0, 0.0), BASE_FRAME, 0))
    half = reflection.compute(rotation, jacobian, 1_000_000, model=((0.0, 0.0, 1.5), 0.5))
    assert half.state == ACTIVE and half.model_share == 0.5
    assert half.joint[2] == pytest.approx(1.0)  # half of 0.5 N and half of 1.5 N, th3's column
    stale = reflection.compute(rotation, jacobian, 1_000_000_000, model=((0.0, 0.0, 1.5), 0.0))
    assert stale.model_share == 1.0 and stale.joint[2] == pytest.approx(1.5)
    nothing = reflection.compute(rotation, jacobian, 1_000_000_000, model=((0.0, 0.0, 0.0), 0.0))
    assert nothing.state != ACTIVE and not any(nothing.actuator)


def test_several_wrench_sources_zero_the_models_force_too_and_it_ramps_in_after():
    # The driver clears the force each cycle while more than one publisher is matched on the
    # wrench topics: every wrench is refused, and "torques zero" must hold in model mode too.
    from kraft_master_driver.core.force_reflection import ACTIVE, ForceReflection, NO_WRENCH
    from kraft_master_driver.core.wrench_admission import BASE_FRAME, WrenchInput
    reflection = ForceReflection(enabled=True, force_ramp_time=0.05)
    rotation = np.eye(3).tolist()
    jacobian = np.eye(6).tolist()
    ms = 1_000_000
    wall = ((0.0, 0.0, 1.5), 1.0)

    def cycles(first, last):
        for cycle in range(first, last):
            reflection.hold(WrenchInput((0.0,) * 6, BASE_FRAME, cycle * ms))
            yield reflection.compute(rotation, jacobian, cycle * ms, model=wall)
    felt = list(cycles(0, 80))[-1]
    assert felt.state == ACTIVE and felt.joint[2] == pytest.approx(1.5)
    reflection.clear()
    cleared = reflection.compute(rotation, jacobian, 80 * ms, model=wall)
    assert cleared.state == NO_WRENCH and not any(cleared.actuator)
    # One source again: its wrench comes, and the model's wall with it, over the ramp.
    after = [output.joint[2] for output in cycles(81, 160)]
    assert after[0] < 0.1 and after[-1] == pytest.approx(1.5)
    assert max(np.diff(after)) <= 1.5 * 0.001 / 0.05 + 1e-9


def test_the_models_force_comes_in_and_goes_out_over_the_ramp_as_the_wrench_stops_and_comes():
    # Direct mode (share 0): the arm's sensor feels nothing and the model holds a wall at 1.5 N.
    # A gap in the wrenches must not step the model's force in at once, nor a wrench coming
    # again step it out.
    from kraft_master_driver.core.force_reflection import ForceReflection
    from kraft_master_driver.core.wrench_admission import BASE_FRAME, WrenchInput
    reflection = ForceReflection(enabled=True, force_ramp_time=0.05)
    rotation = np.eye(3).tolist()
    jacobian = np.eye(6).tolist()
    ms = 1_000_000
    felt = []
    for cycle in range(400):
        if cycle < 100 or cycle >= 250:  # a gap of 150 ms: stale after 50 ms
            reflection.hold(WrenchInput((0.0,) * 6, BASE_FRAME, cycle * ms))
        output = reflection.compute(rotation, jacobian, cycle * ms,
                                    model=((0.0, 0.0, 1.5), 0.0))
        felt.append(output.joint[2])  # th3's column: fz
    assert felt[99] == 0.0 and felt[249] == pytest.approx(1.5) and felt[-1] == 0.0
    assert max(np.abs(np.diff(felt))) <= 1.5 * 0.001 / 0.05 + 1e-9  # 1 ms of the 50 ms ramp
