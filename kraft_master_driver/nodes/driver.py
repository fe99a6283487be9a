# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_node: the ROS 2 driver of one Kraft Master hand controller.

One loop thread owns the device and the timing (wrenches in, torques out, pots in,
kinematics, publish): core.control_loop.ControlLoop, which imports no rclpy. The rclpy
executor spins in the main thread for services, parameters and diagnostics. This module wires
the parts together: parameters, device, force reflection, topics, loop.
"""
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from kraft_master_driver.core import kinematics, realtime
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.core.contact_rendering import ContactRenderer, RendererSettings
from kraft_master_driver.core.control_loop import ControlLoop, LOOP_THREAD
from kraft_master_driver.core.force_mode import (
    ForceMode, ModelFeedback, ModeSelector, ModeSettings)
from kraft_master_driver.core.force_reflection import ForceReflection
from kraft_master_driver.core.gravity import GravityModel
from kraft_master_driver.core.passivity import MasterPort
from kraft_master_driver.core.velocity_filter import VelocityFilter
from kraft_master_driver.core.wrench_admission import BASE_FRAME, WRIST_FRAME
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.link.protocol import ERROR_KINDS, get_codec
from kraft_master_driver.nodes import driver_diagnostics
from kraft_master_driver.nodes.driver_diagnostics import DriverReadings
from kraft_master_driver.nodes.driver_parameters import PARAMETERS, SIM_PORT
from kraft_master_driver.nodes.driver_topics import InputTopics, StateTopics
from kraft_master_driver.nodes.node_process import run_node
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, run_time_changes)
from kraft_master_driver.nodes.ros_io import GIL_SWITCH_INTERVAL_S, steady_timer
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from std_srvs.srv import SetBool, Trigger

DIAGNOSTIC_LEVELS = {driver_diagnostics.OK: DiagnosticStatus.OK,
                     driver_diagnostics.WARN: DiagnosticStatus.WARN,
                     driver_diagnostics.ERROR: DiagnosticStatus.ERROR}
# Parameters settable at run time that the force reflection and the wrench admission take as
# they are.
FORCE_SETTINGS = ('force_scale', 'wrench_timeout', 'torque_limits', 'centre_stiffness',
                  'centre_damping', 'contact_damping', 'force_ramp_time')
ADMISSION_SETTINGS = ('max_force', 'max_moment', 'max_wrench_age', 'max_stamp_skew')


class KraftMasterNode(Node):
    """Publishes the hand controller's state and reflects task wrenches as joint torques."""

    def __init__(self, params_files=(), **kwargs):
        """Declare and check parameters, open the device and start the loop thread."""
        super().__init__('kraft_master_node', **kwargs)
        self.config = declare_parameters(self, PARAMETERS, params_files)
        self.arm = self.config['arm']
        self.calibration = self._calibration()
        self.codec = self._codec()
        self.force = ForceReflection(
            force_scale=self.config['force_scale'],
            torque_limits=tuple(self.config['torque_limits']),
            coupling=self.config['coupling'],
            wrench_timeout=self.config['wrench_timeout'],
            centre_stiffness=tuple(self.config['centre_stiffness']),
            centre_damping=tuple(self.config['centre_damping']),
            contact_damping=self.config['contact_damping'],
            force_ramp_time=self.config['force_ramp_time'])
        self.force.enabled = self.config['force_enabled_at_start']
        self.master_port = MasterPort(self.config['passivity_damping'],
                                      self.config['force_ramp_time'])
        self.master_port.enabled = self.config['passivity']
        self.velocity = VelocityFilter(self.config['velocity_cutoff_hz'])
        self.model = self._model_feedback()

        joint_names = [self.config['joint_prefix'] + n for n in kinematics.JOINT_NAMES]
        self.topics = StateTopics(self, self.config, joint_names, self.master_port)
        self.inputs = InputTopics(self, self.config, self.force, self.master_port, {
            self.config['base_frame']: BASE_FRAME, self.config['wrist_frame']: WRIST_FRAME},
            self.model)
        self.create_service(SetBool, 'enable_force', self._on_enable_force)
        self.create_service(Trigger, 'set_center', self._on_set_center)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        steady_timer(self, 1.0, self._publish_diagnostics)
        self._errors_reported = {}

        self.simulator = self.device = self.loop = self._thread = self._gravity = None
        try:
            self._start_device()
        except BaseException:
            # A stop signal during start-up: what was started is stopped as on any stop.
            self.stop()
            raise
        if self.config['rate_command_enabled']:
            self._say_rate_command_waits_for_centre()
        force = 'enabled' if self.force.enabled else 'disabled (call enable_force)'
        if self.device.link_up:
            self.get_logger().info(
                f'{self.arm} Kraft Master on {self.config["port"]} at '
                f'{self.config["loop_rate_hz"]:g} Hz; force output {force}')
        else:
            self.get_logger().warning(
                f'{self.arm} Kraft Master on {self.config["port"]}: {self.loop.link_state()}; '
                'retrying')

    # -- set-up --------------------------------------------------------------------------

    def _start_device(self):
        """Start the simulator if asked, open the device and start the loop thread."""
        signs = self._torque_signs()
        port = self.config['port']
        if port == SIM_PORT:
            port = self._start_simulator()
        self.device = KmcDevice(
            port, baudrate=self.config['baud'], codec=self.codec,
            reply_timeout=self.config['reply_timeout'],
            torque_scale=self._torque_setting('torque_scale'),
            torque_limit=self._torque_setting('torque_command_limit'),
            torque_sign=signs, low_latency=self.config['low_latency'])
        self.device.open()
        if self.device.link_up and self.device.stats['low_latency_failures']:
            self.get_logger().warning(self.device.last_error)
        self._warn_if_wire_limited()

        self.loop = ControlLoop(
            self.device, self.force, self._publish_state, calibration=self.calibration,
            arm=self.arm, lengths=kinematics.LinkLengths(*self.config['link_lengths']),
            velocity=self.velocity, master_port=self.master_port, log=self.get_logger(),
            rate_hz=self.config['loop_rate_hz'], take_inputs=self.inputs.take,
            publish_decimation=self.config['publish_decimation'],
            priority=self.config['loop_priority'], executor_thread=threading.get_native_id(),
            keep_running=self.context.ok, model=self.model)
        self._update_gravity()
        # Not a daemon: the interpreter waits for the loop to zero the torques on its way out.
        self._thread = realtime.NamedThread(target=self.loop.run, name=LOOP_THREAD)
        self._thread.start()

    def _model_feedback(self):
        """Return the contact model's side (None for force_mode 'direct'); ParameterError."""
        config = self.config
        mode = ForceMode(config['force_mode'])
        if mode is ForceMode.DIRECT:
            return None
        try:
            selector = ModeSelector(ModeSettings(mode, config['model_above'],
                                                 config['direct_below'], config['switch_time']),
                                    config['passivity'])
        except ValueError as error:
            raise ParameterError(f'parameter {error}') from None
        return ModelFeedback(selector, ContactRenderer(RendererSettings(
            config['loop_rate_hz'], config['device_damping'], config['approach_speed'],
            config['update_energy'], config['model_timeout'])))

    def _update_gravity(self):
        """Give the loop the arm's holding torques, or none, as the parameters say."""
        if not self.config['gravity_compensation']:
            self.loop.holding = None
            return
        if self._gravity is None:
            self._gravity = GravityModel(self.arm, self.loop.lengths)
        model, base = self._gravity, tuple(self.config['gravity_parameters'])
        self.loop.holding = lambda theta: model.holding_torques(theta, base).tolist()

    def _calibration(self):
        calibration = {key.split('.', 1)[1]: value for key, value in self.config.items()
                       if key.startswith('calibration.')}
        given = [key for key in calibration if f'calibration.{key}' in self._parameter_overrides]
        if given and len(given) < len(calibration):
            missing = sorted(set(calibration) - set(given))
            raise ParameterError(
                f'parameter calibration.{missing[0]}: missing; a calibration must give all of '
                f'{", ".join("calibration." + key for key in calibration)}')
        try:
            return ArmCalibration.from_parameters(self.arm, calibration, 'parameters')
        except CalibrationError as error:
            raise ParameterError(str(error)) from None

    def _codec(self):
        """Return the codec the codec parameter names; ParameterError (one line) if it cannot."""
        try:
            return get_codec(self.config['codec'])
        except ValueError as error:
            raise ParameterError(f'parameter codec: {error}') from None

    def _torque_signs(self):
        """Return the torque_signs parameter; ParameterError if one is not 1 or -1."""
        signs = tuple(self.config['torque_signs'])
        if not set(signs) <= {1, -1}:
            raise ParameterError(f'parameter torque_signs: {list(signs)}: each must be 1 or -1')
        return signs

    def _torque_setting(self, name):
        """Return a torque parameter given for the node, or None: the codec's then."""
        return tuple(self.config[name]) if name in self._parameter_overrides else None

    def _start_simulator(self):
        from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
        self.simulator = SimulatedKraftMaster(
            arm=self.arm, calibration=self.calibration, codec=self.codec,
            torque_scale=self._torque_setting('torque_scale'),
            coupling=self.config['coupling'], operator=self.config['sim_operator'],
            pot_noise_counts=self.config['sim_noise_counts'],
            priority=self.config['loop_priority'])  # it stands in for hardware: as prompt
        path = self.simulator.start()
        self.get_logger().info(f'simulated hand controller on {path}')
        if self.simulator.priority_error:
            self.get_logger().info(  # the loop's own refusal is the warning that says the fix
                f'simulated hand controller: {self.simulator.priority_error}')
        return path

    def _warn_if_wire_limited(self):
        if self.simulator is not None:
            return
        wire_rate = self.device.wire_limited_rate()
        if wire_rate < self.config['loop_rate_hz']:
            self.get_logger().warning(
                f'at {self.config["baud"]} baud the link carries at most {wire_rate:.0f} '
                f'cycles/s, below loop_rate_hz {self.config["loop_rate_hz"]:g}')

    # -- the loop thread's publish callback ----------------------------------------------

    def _publish_state(self, result, estimate):
        self.topics.publish(result, estimate, self.loop.centre)

    # -- executor callbacks --------------------------------------------------------------

    def _on_enable_force(self, request, response):
        self.force.enabled = bool(request.data)
        if not request.data:
            self.force.clear()
        response.success = True
        response.message = 'force output ' + ('enabled' if request.data else 'disabled')
        self.get_logger().info(response.message)
        return response

    def _on_set_center(self, request, response):
        pose = self.loop.pose()
        response.success = pose is not None
        if pose is None:
            response.message = 'no pose yet: the device has not answered'
        else:
            self.loop.centre = pose
            x, y, z = pose[:3, 3]
            response.message = f'centre set at ({x:.4f}, {y:.4f}, {z:.4f}) m'
        return response

    def _say_rate_command_waits_for_centre(self):
        """Log, once rate_command is enabled without a centre, that it waits for set_center."""
        if self.loop.centre is None:
            self.get_logger().info(
                'rate_command enabled: nothing is published until '
                f"{self.resolve_service_name('set_center')} sets the centre")

    def _on_set_parameters(self, parameters):
        try:
            changes = run_time_changes(PARAMETERS, parameters)
        except ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        settings = {key: tuple(value) if isinstance(value, list) else value
                    for key, value in changes.items()}
        try:
            # check_value kept each within its range, which both take: the second call never
            # refuses after the first has applied its changes.
            self.force.configure(**{key: settings[key] for key in FORCE_SETTINGS
                                    if key in settings})
            self.inputs.admission.configure(**{key: settings[key] for key in ADMISSION_SETTINGS
                                               if key in settings})
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        if changes.get('rate_command_enabled'):
            self.topics.advertise_rate_command()  # before the loop sees it enabled
            if not self.config['rate_command_enabled']:
                self._say_rate_command_waits_for_centre()
        if 'passivity' in changes:
            self.master_port.enabled = changes['passivity']
            if self.model is not None:
                self.model.selector.passivity = changes['passivity']
        if 'passivity_damping' in changes:
            self.master_port.damping = changes['passivity_damping']
        if 'force_ramp_time' in changes:
            self.master_port.rise_time = changes['force_ramp_time']
        if 'velocity_cutoff_hz' in changes:
            self.velocity.cutoff_hz = changes['velocity_cutoff_hz']
        if 'publish_decimation' in changes:
            self.loop.publish_decimation = changes['publish_decimation']
        self.config.update(changes)
        if {'gravity_compensation', 'gravity_parameters'} & set(changes):
            self._update_gravity()
        return SetParametersResult(successful=True)

    def _warn_link_errors(self, device_stats):
        """Name the decoder errors of the last diagnostics period, if there were any."""
        grown = {kind: device_stats[kind] - self._errors_reported.get(kind, 0)
                 for kind in ERROR_KINDS}
        self._errors_reported = {kind: device_stats[kind] for kind in ERROR_KINDS}
        if any(grown.values()):
            self.get_logger().warning(
                'bad bytes from the device, frames dropped: ' + ', '.join(
                    f'{kind} +{count}' for kind, count in grown.items() if count))

    def _publish_diagnostics(self):
        # Stamped when the counters are read: a busy executor may take a while to publish.
        stamp = self.get_clock().now().to_msg()
        device_stats = self.device.stats
        self._warn_link_errors(device_stats)
        admission, output = self.inputs.admission, self.loop.output
        taken_ns = self.inputs.wrench_taken_ns
        level, message, values = driver_diagnostics.driver_diagnostics(DriverReadings(
            statistics=self.loop.statistics, scheduler=self.loop.scheduler,
            executor_scheduler=self.loop.executor_scheduler,
            memory_lock=self.loop.memory_lock, device_stats=device_stats,
            link_state=None if self.device.link_up else self.loop.link_state(),
            force=self.force, force_state=output.state if output else None,
            wrench_sources=admission.sources, sources_refused=admission.sources_refusal(),
            calibration=self.calibration.source, port=self.config['port'],
            master_port=self.master_port, slave_energy=self.inputs.slave_energy,
            slave_link=self.inputs.slave_link.summary(),
            wrench_age=None if taken_ns is None else (time.monotonic_ns() - taken_ns) / 1e9))
        port = self.config['port']
        status = DiagnosticStatus(
            name=f'{self.get_fully_qualified_name()}: {self.arm} Kraft Master',
            hardware_id='simulated KMC 9100' if port == SIM_PORT else f'KMC 9100 on {port}',
            level=DIAGNOSTIC_LEVELS[level], message=message,
            values=[KeyValue(key=k, value=v) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        self.topics.diagnostics.publish(array)

    # -- shutdown ------------------------------------------------------------------------

    def destroy_node(self):
        """Stop the device first (zero torques), then the node."""
        self.stop()
        super().destroy_node()

    def stop(self):
        """Stop the loop thread, write zero torques, close the port and the simulator."""
        if self.loop is not None:
            self.loop.stop()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(timeout=2.0)
        if self.device is not None:
            self.device.close()
        if self.simulator is not None:
            self.simulator.stop()


def main(args=None):
    """Run the driver until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return run_node(KraftMasterNode, 'kraft_master_node', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
