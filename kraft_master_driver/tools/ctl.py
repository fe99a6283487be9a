# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_ctl: call a running driver's services, with or without the ros2 tool.

`kraft_master_ctl force on` is `ros2 service call /enable_force std_srvs/srv/SetBool
"{data: true}"`, and `kraft_master_ctl set_center` is `ros2 service call /set_center
std_srvs/srv/Trigger`. It waits for the driver's service, calls it once, prints the driver's
answer and exits 0, or prints one line and exits 1 when no driver answers or it refuses.
"""
import argparse
import os
import sys

import rclpy
import rclpy.exceptions
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from std_srvs.srv import SetBool, Trigger

PROG = 'kraft_master_ctl'


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit code 1."""

    def error(self, message):
        """Print `message` on one line and exit 1."""
        self.exit(1, f'{PROG}: {message} (see {PROG} --help)\n')


def _positive(text):
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f'must be positive, not {text}')
    return value


def parser():
    """Return the command line's parser."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument('--namespace', default='/',
                        help="the driver's namespace, e.g. /right (default: /)")
    common.add_argument('--timeout', type=_positive, default=10.0,
                        help='seconds to wait for the driver to answer (default: 10)')
    main_parser = Parser(prog=PROG, description=__doc__.split('\n\n')[1].replace('\n', ' '))
    commands = main_parser.add_subparsers(dest='command', required=True, metavar='COMMAND',
                                          parser_class=Parser)
    force = commands.add_parser('force', parents=[common],
                                help='force output on or off (service enable_force)')
    force.add_argument('state', choices=('on', 'off'))
    commands.add_parser('set_center', parents=[common],
                        help='the wrist pose now becomes the centre of rate_command and of the '
                             'return-to-centre spring (service set_center)')
    return main_parser


def service_name(namespace, service):
    """Return the absolute name of `service` in `namespace` ('/', '/right', 'right/')."""
    return '/'.join(['', *filter(None, namespace.split('/')), service])


def call(name, service_type, request, timeout):
    """Call service `name` once; return its response, or raise TimeoutError."""
    context = rclpy.Context()
    rclpy.init(args=[PROG], context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node(f'{PROG}_{os.getpid()}', context=context,
                                 start_parameter_services=False)
        client = node.create_client(service_type, name)
        if not client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f'no driver offers {name} within {timeout:g} s (is '
                               'kraft_master_node running, in that namespace and on this '
                               'ROS_DOMAIN_ID?)')
        future = client.call_async(request)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.spin_until_future_complete(future, timeout_sec=timeout)
        if not future.done():
            raise TimeoutError(f'{name} did not answer within {timeout:g} s')
        return future.result()
    finally:
        rclpy.try_shutdown(context=context)


def main(argv=None):
    """Run one command; return 0 when the driver did it, else 1."""
    args = parser().parse_args(argv)
    if args.command == 'force':
        service, service_type = 'enable_force', SetBool
        request = SetBool.Request(data=args.state == 'on')
    else:
        service, service_type, request = 'set_center', Trigger, Trigger.Request()
    name = service_name(args.namespace, service)
    try:
        response = call(name, service_type, request, args.timeout)
    except rclpy.exceptions.NameValidationException as error:
        print(f'{PROG}: {name!r} is not a valid service name: {error}'.splitlines()[0],
              file=sys.stderr)
        return 1
    except TimeoutError as error:
        print(f'{PROG}: {error}', file=sys.stderr)
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        print(f'{PROG}: interrupted before {name} answered', file=sys.stderr)
        return 1
    if not response.success:
        print(f'{PROG}: {name} refused: {response.message}', file=sys.stderr)
        return 1
    print(f'{name}: {response.message}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
