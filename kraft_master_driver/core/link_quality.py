# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The quality of a link, no ROS: one-way delay and loss of a stream of stamped messages."""


class LinkMonitor:
    """
    One-way delay and loss of a stream of stamped messages, per window.

    Both ends must share a clock (one machine, or hosts synchronised by NTP/PTP). Loss is
    counted from the gaps between stamps against the stream's median interval, so it is the
    share of the stream's ticks that never arrived: lost on the way, or never sent because the
    sender fell behind and skipped them. Without sequence numbers the two look alike.
    """

    def __init__(self) -> None:
        """Start an empty window."""
        self._delays: list[int] = []
        self._stamps: list[int] = []

    def add(self, stamp_ns: int, receipt_ns: int) -> None:
        """Note one message stamped stamp_ns and received at receipt_ns (same clock)."""
        self._delays.append(receipt_ns - stamp_ns)
        self._stamps.append(stamp_ns)

    def summary(self) -> tuple[float, float, float, float] | None:
        """Return (delay median, p99, max in s, lost fraction) of the window and start anew."""
        delays, stamps = sorted(self._delays), sorted(self._stamps)
        self._delays, self._stamps = [], []
        if len(stamps) < 3:
            return None
        gaps = sorted(b - a for a, b in zip(stamps, stamps[1:]))
        interval = gaps[len(gaps) // 2]
        expected = (stamps[-1] - stamps[0]) / interval + 1 if interval > 0 else len(stamps)
        count = len(delays)
        return (delays[count // 2] / 1e9, delays[min(count - 1, int(0.99 * count))] / 1e9,
                delays[-1] / 1e9, max(0.0, 1.0 - len(stamps) / expected))
