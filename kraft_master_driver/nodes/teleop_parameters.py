# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The parameters of kraft_master_teleop: name, default, description with units, range.

The settings of core.teleoperation_settings.Settings are settable at run time (_tunable), but
for the mode and the frames; what is fixed at start-up says why in its description.
"""
import math

from kraft_master_driver.core.teleoperation_settings import (
    MODES, ORIENTATIONS, Settings, SLAVE_PORT_FORCES)
from kraft_master_driver.nodes.parameters import Spec

_DEFAULT = Settings()


def _spec(name, description, **bounds):
    """Return a Spec whose default is core.teleoperation_settings.Settings' value of `name`."""
    default = getattr(_DEFAULT, name)
    return Spec(list(default) if isinstance(default, tuple) else default, description, **bounds)


def _tunable(name, description, **bounds):
    """Return the Spec of a setting that is settable at run time."""
    return _spec(name, description, read_only=False, **bounds)


PARAMETERS = {
    'mode': _spec('mode', "'pose': publish servo_cp, the target pose; 'twist': publish "
                  'servo_cv, a twist toward it (MoveIt Servo). Fixed: it chooses the '
                  'publisher.', choices=MODES),
    'rate_hz': Spec(100.0, 'Rate of the timeout checks, of the hold command while not '
                    "following, and of slave_energy (Hz). Fixed: the input thread's pace is "
                    'set as it starts.', low=1.0, high=2000.0),
    'scale': _tunable('scale', 'Arm motion per master motion (1); a change registers anew.',
                      low=0.001, high=100.0),
    'orientation': _tunable('orientation', "'follow': the arm turns as the master does; "
                            "'fixed': it keeps its orientation at registration; 'ignore': not "
                            'commanded (pose mode sends the measured one, twist mode no '
                            'rotation); a change registers anew.', choices=ORIENTATIONS),
    'base_rotation': _tunable('base_rotation', "Rotation of the master's base frame in the "
                              "arm's base frame: roll, pitch, yaw (rad) or a quaternion x, y, "
                              'z, w; a change registers anew and ramps the wrench.',
                              length=(3, 4)),
    'base_rotation_from_tf': Spec(False, 'At each enable, take base_rotation from TF: the '
                                  'rotation of master_frame in arm_frame (needs tf2_ros). '
                                  'Fixed: the TF listener is created at start-up.'),
    'sensor_rotation': _tunable('sensor_rotation', "Rotation of the F/T sensor's frame in the "
                                'frame of measured_cp: roll, pitch, yaw (rad) or x, y, z, w.',
                                length=(3, 4)),
    'master_frame': _spec('master_frame', "frame_id of pose and wrench: the driver's "
                          "base_frame. Fixed: the wrench's header is laid out once."),
    'arm_frame': _spec('arm_frame', 'frame_id of measured_cp, servo_cp and servo_cv: the '
                       "arm's base frame. Fixed: servo_cp's header is laid out once."),
    'ft_frame': _spec('ft_frame', 'frame_id of measured_cf: the F/T sensor frame. Fixed, as '
                      'the other frames: a frame is wiring, not a tuning.'),
    'workspace_min': _tunable('workspace_min', "Lower corner of the box the arm's target "
                              'stays in (m, arm base frame).', length=3),
    'workspace_max': _tunable('workspace_max', 'Upper corner of that box (m).', length=3),
    'max_linear_speed': _tunable('max_linear_speed', "Speed limit of the arm's target (m/s).",
                                 low=0.001, high=10.0),
    'max_angular_speed': _tunable('max_angular_speed', "Angular speed limit of the arm's "
                                  'target (rad/s).', low=0.001, high=100.0),
    'twist_gain': _tunable('twist_gain', 'Twist mode: servo_cv = gain * (target - measured), '
                           '(1/s).', low=0.001, high=1000.0),
    'master_timeout': _tunable('master_timeout', 'An older pose holds the arm (s).',
                               low=0.001, high=10.0),
    'arm_timeout': _tunable('arm_timeout', 'An older measured_cp is a FAULT (s).',
                            low=0.001, high=10.0),
    'ft_timeout': _tunable('ft_timeout', 'An older measured_cf is a FAULT (s).',
                           low=0.001, high=10.0),
    'max_tracking_error': _tunable('max_tracking_error', 'measured_cp farther from the '
                                   'command is a FAULT (m).', low=0.0001, high=10.0),
    'max_tracking_angle': _tunable('max_tracking_angle', 'measured_cp turned farther from the '
                                   'command is a FAULT (rad).', low=0.0001, high=math.pi),
    'force_feedback': _tunable('force_feedback', 'Reflect measured_cf to the master; false: '
                               'no F/T sensor, zero wrench.'),
    'tool_mass': _tunable('tool_mass', 'Mass of the tool beyond the sensor (kg).',
                          low=0.0, high=100.0),
    'tool_com': _tunable('tool_com', "The tool's centre of mass (m, sensor frame).",
                         length=3),
    'gravity': _tunable('gravity', 'Gravity (m/s^2, arm base frame).', length=3),
    'force_scale': _tunable('force_scale', 'Master force per arm force (1).',
                            low=0.0, high=100.0),
    'moment_scale': _tunable('moment_scale', 'Master moment per arm moment (1).',
                             low=0.0, high=100.0),
    'force_deadband': _tunable('force_deadband', 'Forces below this are not reflected (N, '
                               'master side).', low=0.0, high=100.0),
    'moment_deadband': _tunable('moment_deadband', 'Moments below this are not reflected '
                                '(N*m).', low=0.0, high=10.0),
    'force_cutoff_hz': _tunable('force_cutoff_hz', 'Cutoff of the first-order low-pass on the '
                                'wrench (Hz); 0: none.', low=0.0, high=1000.0),
    'force_resume_time': _tunable('force_resume_time', "Seconds over which the master's "
                                  'wrench comes in from zero as the bridge starts following '
                                  '(an enable, a clutch release, a fresh pose after a hold); '
                                  '0: at once.', low=0.0, high=1.0),
    'max_force': _tunable('max_force', 'Largest force sent to the master (N).',
                          low=0.0, high=200.0),
    'max_moment': _tunable('max_moment', 'Largest moment sent to the master (N*m).',
                           low=0.0, high=20.0),
    'arm_stiffness': _tunable('arm_stiffness', "Translational stiffness of the arm's impedance "
                              '(N/m): the force sent is at most it times how far the command '
                              "is from the measured tool, so the tool's impacts do not kick the "
                              'master; 0: no limit.', low=0.0, high=1e6),
    'max_input_force': _tunable('max_input_force', 'A larger measured_cf force is refused '
                                '(N).', low=1.0, high=1e5),
    'max_input_moment': _tunable('max_input_moment', 'A larger measured_cf moment is refused '
                                 '(N*m).', low=0.1, high=1e4),
    'max_input_position': _tunable('max_input_position', 'A pose or measured_cp farther from '
                                   'its base is refused (m).', low=0.1, high=1000.0),
    'passivity': _tunable('passivity', "Time-domain passivity control of the arm's command, "
                          'fed by master_energy; a change registers anew.'),
    'drift_gain': _tunable('drift_gain', 'Rate at which passivity drift is given back (1/s).',
                           low=0.0, high=1000.0),
    'slave_port_force': _tunable('slave_port_force', "The force passivity's slave port books "
                                 "against the arm's command: 'contact', the F/T contact force; "
                                 "'sent', the force sent to the master, in its units, and no "
                                 "moment unless orientation is 'follow' (see doc/passivity.md).",
                                 choices=SLAVE_PORT_FORCES),
    'arm_hold_timeout': _tunable('arm_hold_timeout', 'A measured_cp or measured_cf older '
                                 'than this (s) holds the arm where it was last sent, the '
                                 'master free and told no contact, until both are fresh again '
                                 'and the arm still (registered anew where the arm is '
                                 'measured); arm_timeout and '
                                 'ft_timeout FAULT later.', low=0.001, high=10.0),
    'model_tolerance': _tunable('model_tolerance', 'Force (N) by which the arm may press harder '
                                'than the contact model the master was last sent; beyond it the '
                                "arm's target goes no deeper into the surface until the force "
                                'is back within half of it; 0: no such limit, the arm yields by '
                                'its impedance alone.', low=0.0, high=1e4),
    'enable_at_start': Spec(False, 'Enable once, as soon as enable would succeed (for launch '
                            'files); false: wait for the enable service. Fixed: it acts at '
                            'start-up.'),
    'clutch_button': Spec(-1, 'Index of the joy button that clutches; -1: no joy topic. '
                          'Fixed: the joy subscription exists only with a button.',
                          low=-1, high=127),
    'input_priority': Spec(0, 'SCHED_FIFO priority of the thread that takes the streaming '
                           "inputs and sends servo_cp, servo_cv and wrench, the executor's "
                           'thread one below; 0: normal scheduling. Fixed: set as that thread '
                           'starts.', low=0, high=98),
}
