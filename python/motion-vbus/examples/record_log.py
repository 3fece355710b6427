"""Record a virtual bus with python-can's ``can.Logger``, as any python-can program would.

    python3 python/motion-vbus/examples/record_log.py --bus can0 --log can0.log --seconds 10
    target/debug/canbus replay can0.log vbus:other          # plays it back, keeping its timing

``can.Logger`` picks the format by the file's suffix: ``.log`` is the candump ``-l`` format that
``canbus replay`` and ``canbus dump --log`` share (python-can adds `` R`` after each received
frame, which ``canbus`` ignores); ``.asc``, ``.blf``, ``.csv`` ... are python-can's others. A
``can.Notifier`` feeds the logger from its own thread. The script records until ``--seconds``
have passed or the ``--stop-file`` exists, prints ``recording vbus:NAME`` once it is on the bus
and ``N frames recorded`` at the end (exit 0); ``tests/tests/python_can.rs`` runs it beside a
coordinator.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import can


class Counter(can.Listener):
    """Counts the frames the notifier hands out."""

    def __init__(self) -> None:
        self.frames = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.frames += 1


def seconds(text: str) -> float:
    """A recording time: finite, 0.01 s to a day."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and 0.01 <= v <= 86_400):
        raise argparse.ArgumentTypeError(f"{text}: give seconds, 0.01 to 86400")
    return v


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bus", required=True, help="the bus name, NAME or vbus:NAME")
    p.add_argument("--log", required=True, help="the log file; its suffix picks the format (.log: candump)")
    p.add_argument("--seconds", type=seconds, default=10.0, help="how long to record (default 10)")
    p.add_argument("--stop-file", help="stop early once this file exists")
    a = p.parse_args()

    counter = Counter()
    with can.Bus(interface="vbus", channel=a.bus) as bus:
        logger = can.Logger(a.log)
        notifier = can.Notifier(bus, [logger, counter])
        print(f"recording vbus:{bus.bus_name} into {a.log}", flush=True)
        end = time.monotonic() + a.seconds
        while time.monotonic() < end and not (a.stop_file and os.path.exists(a.stop_file)):
            time.sleep(0.01)
        # The notifier first, so that the logger gets no frame after it closed its file.
        notifier.stop()
        logger.stop()
    print(f"{counter.frames} frames recorded", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
