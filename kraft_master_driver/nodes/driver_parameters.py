# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The parameters of kraft_master_node: name, default, description with units, range."""
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.contact_rendering import RendererSettings
from kraft_master_driver.core.force_mode import ForceMode, ModeSettings
from kraft_master_driver.core.gravity import BASE_NAMES
from kraft_master_driver.link.protocol import (
    CODECS, DEFAULT_CODEC, DEFAULT_TORQUE_LIMIT, DEFAULT_TORQUE_SCALE)
from kraft_master_driver.nodes.parameters import Spec

# The port that starts the built-in simulated hand controller.
SIM_PORT = 'sim'

_NOMINAL = ArmCalibration.nominal('right').to_parameters()['calibration']
_MODE, _WALL = ModeSettings(), RendererSettings()

PARAMETERS = {
    'arm': Spec('right', 'Which unit: right or left (the left arm mirrors L3).',
                choices=kinematics.ARMS),
    'port': Spec('/dev/ttyUSB0', 'Serial device path or pyserial URL of the KMC 9100; "sim" '
                 'starts the built-in simulated hand controller on a pseudo-terminal.'),
    'baud': Spec(1_000_000, 'Serial baud rate (bit/s).', low=1200, high=12_000_000),
    'codec': Spec(DEFAULT_CODEC, 'Frame of the serial link: a built-in description ('
                  f'{", ".join(sorted(CODECS))}) or the path of a frame description .yaml '
                  '(doc/device-link.md).'),
    'low_latency': Spec(False, 'Put the serial port into the kernel low-latency mode.'),
    'reply_timeout': Spec(0.01, 'Time to wait for the pot frame of a cycle (s).',
                          low=0.0005, high=1.0),
    'loop_rate_hz': Spec(1000.0, 'Rate of the device cycle (Hz).', low=1.0, high=5000.0),
    'loop_priority': Spec(
        50, 'SCHED_FIFO priority of the loop thread (1-99; 0 = the normal scheduler). Where '
        'the OS refuses it (no CAP_SYS_NICE or rtprio limit), a warning and the normal one.',
        low=0, high=99),
    'publish_decimation': Spec(1, 'Publish state every Nth cycle (1 = every cycle).',
                               read_only=False, low=1, high=1000),
    'link_lengths': Spec(list(kinematics.NOMINAL_LENGTHS),
                         'Link lengths L1, L2, L3, L4 (m); L3 positive for both arms.',
                         low=0.001, high=2.0, length=4),
    'calibration.pot_a': Spec(_NOMINAL['pot_a'], 'Pot counts at angle_a, POT1..POT6.',
                              low=0.0, high=4095.0, length=6),
    'calibration.pot_b': Spec(_NOMINAL['pot_b'], 'Pot counts at angle_b, POT1..POT6.',
                              low=0.0, high=4095.0, length=6),
    'calibration.angle_a_deg': Spec(_NOMINAL['angle_a_deg'], 'Angle read at pot_a (deg).',
                                    low=-360.0, high=360.0, length=6),
    'calibration.angle_b_deg': Spec(_NOMINAL['angle_b_deg'], 'Angle read at pot_b (deg).',
                                    low=-360.0, high=360.0, length=6),
    'torque_scale': Spec([float(x) for x in DEFAULT_TORQUE_SCALE],
                         'Device command counts per N*m, axes 1..5; when not given, the '
                         "codec's counts_per_nm (the default shown is kraft-default's).",
                         low=1e-6, high=1e6, length=5),
    'torque_command_limit': Spec([int(x) for x in DEFAULT_TORQUE_LIMIT],
                                 'Clamp of the device command, counts, axes 1..5; when not '
                                 "given, the codec's limit (the default shown is "
                                 "kraft-default's).",
                                 low=1, high=32767, length=5),
    'torque_signs': Spec([1] * 5, 'Sign of each actuator axis 1..5, 1 or -1, multiplying its '
                         'command counts after the clamp; kraft_master_calibrate '
                         '--check-torques measures it and writes it into the calibration file.',
                         low=-1, high=1, length=5),
    'torque_limits': Spec([2.0] * 5, 'Largest actuator torque per axis 1..5 (N*m); above it '
                          'the whole torque vector is scaled down together.',
                          read_only=False, low=0.001, high=100.0, length=5),
    'coupling': Spec('actuator', 'Torque form on channels 2 and 3: "actuator" (elbow motor '
                     'drives th2 + th3) or "joint".', choices=('actuator', 'joint')),
    'force_scale': Spec(1.0, 'Scale from task wrench to reflected wrench (1).',
                        read_only=False, low=0.0, high=10.0),
    'wrench_timeout': Spec(0.05, 'A wrench older than this gives zero torque (s).',
                           read_only=False, low=0.001, high=5.0),
    'max_wrench_age': Spec(0.1, 'A wrench whose stamp is older than this gives zero torque '
                           '(s); across a delayed link, set it above the one-way delay.',
                           read_only=False, low=0.001, high=10.0),
    'max_stamp_skew': Spec(1.0, 'Wrenches stamped further than this from the system clock are '
                           'rejected (s); an unset stamp (0) is accepted.',
                           read_only=False, low=0.001, high=1e9),
    'max_force': Spec(200.0, 'Wrenches with a larger force are rejected (N).',
                      read_only=False, low=0.0, high=1e4),
    'max_moment': Spec(20.0, 'Wrenches with a larger moment are rejected (N*m).',
                       read_only=False, low=0.0, high=1e3),
    'force_enabled_at_start': Spec(False, 'Force output enabled at start-up; else call '
                                   'the enable_force service.'),
    'centre_stiffness': Spec([0.0, 0.0], 'Return-to-centre stiffness: linear (N/m), angular '
                             '(N*m/rad).', read_only=False, low=0.0, high=1e4, length=2),
    'centre_damping': Spec([0.0, 0.0], 'Return-to-centre damping: linear (N*s/m), angular '
                           '(N*m*s/rad).', read_only=False, low=0.0, high=1e3, length=2),
    'contact_damping': Spec(0.0, 'Damping of the wrist in contact, per newton of the force '
                            'reflected (N*s/m per N, i.e. s/m): none in free space; it keeps a '
                            'stiff contact reflected through a lagging arm still.',
                            read_only=False, low=0.0, high=100.0),
    'force_ramp_time': Spec(0.05, 'After torques were zeroed (force disabled, a stale or '
                            'refused wrench, no reply from the device, a gap in the cycles), '
                            'the force comes back from zero over this time (s); with '
                            'passivity on, the share of the force its port lets through '
                            'rises no faster. 0: at once.',
                            read_only=False, low=0.0, high=1.0),
    'gravity_compensation': Spec(False, 'Add the motor torques that hold the arm up against '
                                 'its weight (from gravity_parameters) while force output is '
                                 'enabled: alone before any wrench, with a live one; zero when '
                                 'the wrench is stale or refused.',
                                 read_only=False),
    'gravity_parameters': Spec([0.0] * len(BASE_NAMES), "The arm's gravity base parameters "
                               f'{", ".join(BASE_NAMES)} (kg*m), as kraft_master_calibrate '
                               '--identify-gravity writes them into the calibration file.',
                               read_only=False, low=-10.0, high=10.0, length=len(BASE_NAMES)),
    'rate_command_enabled': Spec(False, 'Publish rate_command (pose minus centre, times gain) '
                                 'once set_center has set the centre, nothing before; the '
                                 'topic exists from the first time this is true.',
                                 read_only=False),
    'rate_gain': Spec([1.0, 1.0], 'Rate command gains: linear (1/s), angular (1/s).',
                      read_only=False, low=0.0, high=100.0, length=2),
    'velocity_cutoff_hz': Spec(50.0, 'Low-pass cut-off of the joint velocity filter (Hz).',
                               read_only=False, low=0.1, high=1000.0),
    'base_frame': Spec('kraft_master_base', 'frame_id of the base frame {0}.'),
    'wrist_frame': Spec('kraft_master_wrist', 'frame_id of the wrist frame {6}.'),
    'joint_prefix': Spec('', 'Prefix of the joint names, e.g. "left_" for two arms.'),
    'sim_operator': Spec('hold', 'Simulated operator hand (port "sim"): hold, sweep, '
                         'random_walk, push or task.',
                         choices=('hold', 'sweep', 'random_walk', 'push', 'task')),
    'sim_noise_counts': Spec(0.0, 'Pot noise of the simulated device (counts, 1 sigma).',
                             low=0.0, high=100.0),
    'allow_multiple_wrench_sources': Spec(
        False, 'Accept wrenches while more than one publisher is matched on wrench; by '
        'default torques are zero then, as two sources would interleave their forces.'),
    'crtk_names': Spec(False, 'Also answer under CRTK names: publish measured_js and '
                       'measured_cp (joint_states and pose again) and take servo_cf (as wrench; '
                       'one source across both).'),
    'passivity': Spec(False, 'Time-domain passivity control of the reflected wrench, fed by '
                      "the slave_energy topic; with force_mode 'auto', the contact model at "
                      'any round trip instead; false: plain J^T F.', read_only=False),
    'passivity_damping': Spec(0.0, 'With passivity on, a damper on the wrist (N*s/m) whose '
                              'energy the master port books as energy in: what the hand puts '
                              'into it lets the arm press before the contact force has crossed '
                              'back.',
                              read_only=False, low=0.0, high=100.0),
    'force_mode': Spec(str(_MODE.mode), "What the operator feels: 'direct', the wrench that "
                       "crossed the link (J^T F); 'model', the arm's contact model "
                       "(contact_model) rendered as a wall in the loop; 'auto', direct below "
                       'model_above of measured round trip and the model above it, and the '
                       'model at any round trip with passivity on.',
                       choices=tuple(ForceMode)),
    'model_above': Spec(_MODE.model_above, "force_mode 'auto': the round trip (s) above which "
                        'the model is rendered.', low=0.0, high=10.0),
    'direct_below': Spec(_MODE.direct_below, "force_mode 'auto': the round trip (s) below "
                         'which direct force comes back (at most model_above).',
                         low=0.0, high=10.0),
    'switch_time': Spec(_MODE.switch_time, 'Seconds over which a change of mode blends the two '
                        'forces.', low=0.0, high=10.0),
    'device_damping': Spec(_WALL.device_damping, "The device's own viscous damping in its least "
                           'damped direction (N*s/m): the model is rendered no stiffer than '
                           '2 * device_damping * loop_rate_hz (N/m; Colgate and Schenkel). The '
                           "default is the simulated device's.", low=0.0, high=100.0),
    'approach_speed': Spec(_WALL.approach_speed, 'Speed (m/s) at which a surface that arrived '
                           "past the hand moves to the model's place.", low=0.001, high=1.0),
    'update_energy': Spec(_WALL.update_energy, 'Energy (J) one model update may put into the '
                          "operator's hand.", low=0.0, high=1.0),
    'model_timeout': Spec(_WALL.model_timeout, 'A contact model not sent again within this '
                          'is gone: no wall (s).', low=0.01, high=10.0),
}
