# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
rclpy's raw I/O for the package's nodes and tools: every low-level rclpy call is here.

As crtk_python_client's ral_ros2.py does for its clients, this module holds what the package
asks of rclpy beyond creating nodes, publishers and services, so that an rclpy upgrade touches
one file:

- subscribe_raw(): a subscription whose messages a thread of the node takes, never the
  executor (TakenByLoopThread): CDR bytes, best effort (which takes reliable and best-effort
  publishers alike), no QoS event handlers (each is work for every wake-up of the executor);
- take_all(), take_all_received(), take_newest(), take_oldest_received(): the messages that
  came on a subscription, CDR bytes for a raw one and typed messages otherwise, with when DDS
  received them where asked; publisher_count();
- InputWaitSet: a wait on a given set of subscriptions alone, with a timeout;
- run_paced() and PacedThread: cycles on core.pacing.Pacer's grid, with its rule for a late
  cycle (run at once, skip the whole periods missed, never a burst); forward_inputs(): a
  thread's work done at each arrival on an InputWaitSet;
- RepeatedRequest: a service request asked again while its answer does not come;
- steady_timer(), GIL_SWITCH_INTERVAL_S, and RCLError.

Private rclpy is used here and nowhere else in the package, only where no public API does the
job:

- rclpy.impl.implementation_singleton's WaitSet: rclpy waits in public only inside its
  executor, on every entity of its nodes, rebuilding its wait set at each wake-up;
- its RCLError: what rclpy.init() and rclpy.try_shutdown() raise on an rcl error, which rclpy
  exports under no public name;
- Subscription.handle's take_message(): the handle is public, but rclpy takes a message in
  public only inside its executor (and wait_for_message, which creates its own subscription).
"""
from contextlib import ExitStack, nullcontext
import threading
import time
from typing import Any, Callable, Iterator, Sequence

from kraft_master_driver.core.pacing import Pacer
from rclpy.callback_groups import CallbackGroup
from rclpy.client import Client
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from rclpy.task import Future
from rclpy.timer import Timer

# The interpreter's switch interval (s) for processes with a paced thread: that thread must
# get the GIL soon after it wakes, not up to 5 ms (the default) later.
GIL_SWITCH_INTERVAL_S = 0.0002
# The longest a paced thread waits on its inputs before it checks whether to stop (s).
INPUT_WAIT_S = 0.02

RCLError: type[Exception] = _rclpy.RCLError


def steady_timer(node: Node, period_s: float, callback: Callable[[], object]) -> Timer:
    """
    Return a timer of `node` on the steady clock.

    A timer on the node's clock stops under use_sim_time while no /clock is published; the
    diagnostics and the periodic log must not.
    """
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


class RepeatedRequest:
    """
    One request at a time to a service; one unanswered for `patience_s` s is asked again.

    A server can take a request and its answer never come to a client just started: rmw_fastrtps
    drops an answer to a client whose reader it has not matched yet, and a restarted link lost
    one under load without the bridge saying so (doc/safety.md). A request given up is removed
    from the client: a late answer to it is ignored (test/unit/nodes/test_repeated_request.py).
    Only for requests that may be made twice.
    """

    def __init__(self, client: Client, patience_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Ask through `client`; `clock` (s) times the wait for an answer."""
        self.client, self.patience_s, self._clock = client, patience_s, clock
        self._pending: Future | None = None
        self._asked_at = 0.0

    def waiting(self) -> bool:
        """Return whether a request waits for its answer, for less than `patience_s` so far."""
        return (self._unanswered() is not None
                and self._clock() - self._asked_at < self.patience_s)

    def overdue(self) -> bool:
        """Return whether a request has waited `patience_s` or more and is not answered."""
        return self._unanswered() is not None and not self.waiting()

    def ask(self, request: Any, on_answer: Callable[[Future], object]) -> bool:
        """
        Send `request` unless one waits for its answer; return whether it was sent.

        An overdue request is given up first. `on_answer` gets the future once answered.
        Nothing is sent while no server is matched.
        """
        pending = self._unanswered()
        if pending is not None:
            if self.waiting():
                return False
            self.client.remove_pending_request(pending)
            self._pending = None
        if not self.client.service_is_ready():
            return False
        self._pending = self.client.call_async(request)
        self._pending.add_done_callback(on_answer)  # type: ignore[no-untyped-call]
        self._asked_at = self._clock()
        return True

    def _unanswered(self) -> Future | None:
        """Return the request's future while its answer has not come."""
        pending = self._pending
        # rclpy leaves Future's methods unannotated.
        if pending is None or pending.done():  # type: ignore[no-untyped-call]
            return None
        return pending


class TakenByLoopThread(CallbackGroup):
    """
    A callback group the executor never waits on: the loop thread takes its messages.

    A wrench is then read in the cycle that uses it, and the executor thread does not compete
    with the loop for the interpreter lock on every message (about 0.3 ms each, measured).
    """

    def can_execute(self, entity: object) -> bool:
        """Never: the executor leaves these entities alone."""
        return False

    def beginning_execution(self, entity: object) -> bool:
        """Never: the executor leaves these entities alone."""
        return False

    def ending_execution(self, entity: object) -> None:
        """Nothing to release."""


def subscribe_raw(node: Node, msg_type: Any, topic: str, callback: Callable[..., Any],
                  depth: int) -> Subscription:
    """
    Subscribe to `topic` for a thread of `node` to take, `depth` messages deep.

    The messages come as CDR bytes; `callback` is the subscription's, for the thread that takes
    them to call (the executor never does).
    """
    # rclpy leaves QoSProfile's constructor (**kwargs) unannotated.
    qos = QoSProfile(  # type: ignore[no-untyped-call]
        depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)
    return node.create_subscription(
        msg_type, topic, callback, qos, raw=True,
        callback_group=TakenByLoopThread(),
        event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))


def _received_ns(info: dict[str, int]) -> int:
    """When DDS received a message (system clock, ns); now if the middleware does not say."""
    return info['received_timestamp'] or time.time_ns()


def take_all(subscription: Subscription) -> Iterator[Any]:
    """Yield each message that came, oldest first: CDR bytes if raw, else typed."""
    handle, msg_type, raw = subscription.handle, subscription.msg_type, subscription.raw
    with handle:
        while (taken := handle.take_message(msg_type, raw)) is not None:
            yield taken[0]


def take_all_received(subscription: Subscription) -> Iterator[tuple[Any, int]]:
    """Yield (message, when DDS received it in ns) of each one that came, oldest first."""
    handle, msg_type, raw = subscription.handle, subscription.msg_type, subscription.raw
    with handle:
        while (taken := handle.take_message(msg_type, raw)) is not None:
            yield taken[0], _received_ns(taken[1])


def take_newest(subscription: Subscription) -> Any:
    """Return the newest message that came, None if none did; the older ones are dropped."""
    newest = None
    for newest in take_all(subscription):
        pass
    return newest


def take_oldest_received(subscription: Subscription) -> tuple[Any, int] | None:
    """Return (the oldest message that came, when DDS received it in ns), or None."""
    handle = subscription.handle
    with handle:
        taken = handle.take_message(subscription.msg_type, subscription.raw)
    return None if taken is None else (taken[0], _received_ns(taken[1]))


def publisher_count(*subscriptions: Subscription | None) -> int:
    """Return how many publishers are matched on these subscriptions together (None: none)."""
    count = 0
    for subscription in subscriptions:
        if subscription is not None:
            count += subscription.get_publisher_count()
    return count


class InputWaitSet:
    """
    A wait on a given set of subscriptions alone, with a timeout.

    Enter it in the thread that waits: while it is entered, the context and the subscriptions
    are held in use, so that neither is destroyed under a wait.
    """

    def __init__(self, context: Context, subscriptions: Sequence[Subscription]) -> None:
        """Wait on `subscriptions` of `context`, once entered."""
        self._context = context
        self._subscriptions = tuple(subscriptions)
        self._handles: tuple[Any, ...] = ()
        self._wait_set: Any = None
        self._in_use = ExitStack()

    def __enter__(self) -> 'InputWaitSet':
        """Hold the context and the subscriptions in use; make the wait set."""
        context = self._context.handle
        if context is None:
            raise RuntimeError('the context is not initialized')
        with ExitStack() as in_use:
            in_use.enter_context(context)
            self._handles = tuple(subscription.handle for subscription in self._subscriptions)
            for handle in self._handles:
                in_use.enter_context(handle)
            self._wait_set = _rclpy.WaitSet(len(self._handles), 0, 0, 0, 0, 0, context)
            self._in_use = in_use.pop_all()
        return self

    def __exit__(self, *exc_info: object) -> None:
        """Let the context and the subscriptions go."""
        self._in_use.close()

    def wait(self, timeout_s: float) -> None:
        """Return once a message waits on any of the subscriptions, or after timeout_s."""
        wait_set = self._wait_set
        wait_set.clear_entities()
        for handle in self._handles:
            wait_set.add_subscription(handle)
        wait_set.wait(max(int(timeout_s * 1e9), 0))


def _nothing() -> None:
    """Do nothing: run_paced's on_input without inputs."""


def run_paced(period_s: float, cycle: Callable[[int], object],
              keep_running: Callable[[], bool], inputs: InputWaitSet | None = None,
              on_input: Callable[[], object] = _nothing) -> None:
    """
    Call cycle(missed) at each deadline, `period_s` apart, until keep_running() is false.

    The grid of deadlines and the rule for a late cycle are core.pacing.Pacer's: a late cycle
    runs at once, `missed` being the whole periods skipped since its deadline (0 on time), and
    the next keeps the grid's phase. Between cycles the thread sleeps or, with `inputs`, waits
    on them, at most INPUT_WAIT_S at a time, and calls on_input() at each wake-up (a late cycle
    too has one first). An exception ends the loop, and is raised only if keep_running() is
    still true: once the context is shut down, waiting, taking and publishing fail.
    """
    pacer = Pacer(round(period_s * 1e9))
    try:
        with inputs if inputs is not None else nullcontext():
            pacer.restart()
            missed = pacer.advance()
            while keep_running():
                if inputs is not None:
                    inputs.wait(min(pacer.seconds_left(), INPUT_WAIT_S))
                    on_input()
                    if pacer.seconds_left() > 0.0:
                        continue
                elif missed is None:
                    pacer.sleep()
                cycle(0 if missed is None else missed)
                missed = pacer.advance()
    except Exception:  # noqa: B902 - see the docstring
        if keep_running():
            raise


def forward_inputs(inputs: InputWaitSet, on_input: Callable[[], object],
                   keep_running: Callable[[], bool]) -> None:
    """
    Call on_input() at each wake-up of a wait on `inputs` until keep_running() is false.

    A wait lasts at most INPUT_WAIT_S. An exception ends the loop as in run_paced().
    """
    try:
        with inputs:
            while keep_running():
                inputs.wait(INPUT_WAIT_S)
                on_input()
    except Exception:  # noqa: B902 - see run_paced's docstring
        if keep_running():
            raise


class PacedThread:
    """A node's thread that runs cycle(missed) by run_paced() until stop() or the context's end."""

    def __init__(self, node: Node, name: str, period_s: float,
                 cycle: Callable[[int], object]) -> None:
        """Make the thread `name`; start() starts it."""
        self._context = node.context
        self._running = True
        self._thread = threading.Thread(target=run_paced, args=(period_s, cycle, self.running),
                                        name=name)

    def start(self) -> None:
        """Start the cycles: the first a period from now."""
        self._thread.start()

    def running(self) -> bool:
        """Return whether the cycles go on: not stopped, and the context not shut down."""
        return self._running and self._context.ok()

    def stop(self) -> None:
        """Stop after the cycle under way; return once the thread has ended."""
        self._running = False
        self._thread.join()
