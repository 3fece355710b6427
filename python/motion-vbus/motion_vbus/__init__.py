"""python-can interface for the motion coordinator's cross-process virtual CAN bus, ``vbus:NAME``.

The bus is one iceoryx2 publish-subscribe service, ``vbus/NAME``, with the 32-byte payload
:class:`CanSample`; every endpoint owns one publisher and one subscriber on it. The layout, the
service's settings and the timing rules are the Rust side's (``drivers::can::shm_bus``, whose
module documentation is the reference); ``tests/tests/python_can.rs`` checks that both sides
agree frame for frame.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import threading
import time
from typing import Any, Optional

import can
import iceoryx2 as iox2

__all__ = [
    "CanSample",
    "VbusBus",
    "worst_case_bits",
    "frame_duration_ns",
    "completion_time_ns",
    "service_name",
]

#: Publishers and subscribers a bus service allows (one of each per endpoint).
MAX_ENDPOINTS = 32
#: iceoryx2 nodes a bus service allows.
MAX_NODES = 64
#: Samples a subscriber buffers before the oldest is overwritten.
SUBSCRIBER_BUFFER = 512
#: Worst-case frames of modelled backlog a sender may queue.
TX_BACKLOG_FRAMES = 64
#: Seconds between two looks at the bus while waiting for a frame (the Rust side's 100 µs).
POLL_INTERVAL = 100e-6
#: Classic CAN's bitrates, bit/s.
MIN_BITRATE = 20_000
MAX_BITRATE = 1_000_000
#: The iceoryx2 payload type name; equal to the Rust ``#[type_name]``.
TYPE_NAME = "motion::vbus::CanSample"

CAN_EFF_FLAG = 0x8000_0000
CAN_RTR_FLAG = 0x4000_0000
CAN_ERR_FLAG = 0x2000_0000


class CanSample(ctypes.Structure):
    """One CAN frame on the bus (``#[repr(C)]`` ``ShmCanSample``, 32 bytes, host byte order)."""

    _fields_ = [
        ("sender", ctypes.c_uint64),
        ("timestamp_ns", ctypes.c_uint64),
        ("can_id", ctypes.c_uint32),
        ("len", ctypes.c_uint8),
        ("reserved", ctypes.c_uint8 * 3),
        ("data", ctypes.c_uint8 * 8),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name (equal to the Rust one)."""
        return TYPE_NAME


def service_name(bus: str) -> str:
    """The iceoryx2 service name of bus ``bus``."""
    return f"vbus/{bus}"


def worst_case_bits(extended: bool, data_len: int) -> int:
    """Worst-case stuffed frame length in bits, with the 3-bit intermission
    (``drivers::can::bit_timing::worst_case_bits``)."""
    n = data_len * 8
    nominal = (67 if extended else 47) + n
    stuffed = (54 if extended else 34) + n
    return nominal + (stuffed - 1) // 4


def frame_duration_ns(extended: bool, remote: bool, dlc: int, bitrate: int) -> int:
    """The worst-case time a frame takes on the wire, ns, rounded up (a remote frame carries
    no data bytes)."""
    bits = worst_case_bits(extended, 0 if remote else dlc)
    return -(-bits * 1_000_000_000 // bitrate)


def completion_time_ns(now: int, prev_end: int, duration: int, max_backlog: int) -> Optional[int]:
    """When a frame of ``duration`` queued at ``now`` behind a frame ending at ``prev_end``
    completes; ``None`` when the backlog would exceed ``max_backlog`` (all ns)."""
    start = max(now, prev_end)
    if start - now > max_backlog:
        return None
    return start + duration


def _monotonic_ns() -> int:
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


_counter = itertools.count()


def _unique_sender_id() -> int:
    # As the Rust side: the pid in the high half, the clock's low bits and a counter below.
    salt = _monotonic_ns() & 0xFFFF_0000
    return (os.getpid() << 32) | ((salt ^ next(_counter)) & 0xFFFF_FFFF)


def _bus_name(channel: Any) -> str:
    if not isinstance(channel, str):
        raise ValueError(f"channel {channel!r}: give the bus name as text, e.g. 'can0' or 'vbus:can0'")
    name = channel[len("vbus:"):] if channel.startswith("vbus:") else channel
    if not name:
        raise ValueError(f"channel {channel!r}: the bus name is empty (e.g. 'can0' or 'vbus:can0')")
    return name


class VbusBus(can.BusABC):
    """An endpoint on ``vbus:NAME``: ``can.Bus(interface="vbus", channel="NAME")``.

    :param channel: the bus name, ``"NAME"`` or ``"vbus:NAME"``.
    :param bitrate: the bitrate this endpoint models its frames at, bit/s (20 000 to 1 000 000;
        default 1 000 000), as the Rust endpoints do.
    :param can_filters: python-can's filters (applied here, in software).
    """

    def __init__(
        self,
        channel: Any = "can0",
        can_filters: Optional[can.typechecking.CanFilters] = None,
        bitrate: int = MAX_BITRATE,
        **kwargs: object,
    ) -> None:
        name = _bus_name(channel)
        if isinstance(bitrate, bool) or not isinstance(bitrate, int):
            raise ValueError(f"bitrate {bitrate!r}: give bit/s as a whole number, {MIN_BITRATE} to {MAX_BITRATE}")
        if not MIN_BITRATE <= bitrate <= MAX_BITRATE:
            raise ValueError(f"bitrate {bitrate}: classic CAN runs at {MIN_BITRATE} to {MAX_BITRATE} bit/s")
        self.bus_name = name
        self.bitrate = bitrate
        self.channel_info = f"vbus:{name} at {bitrate} bit/s"
        self._sender = _unique_sender_id()
        # Frames carry CLOCK_MONOTONIC times; python-can's (and `canbus dump`'s logs) are Unix
        # epoch seconds: shift by the difference of the two clocks, taken once, as canbus does.
        self.wall_offset_ns = time.time_ns() - _monotonic_ns()
        self._tx_end = 0
        self._max_backlog = -(-worst_case_bits(True, 8) * TX_BACKLOG_FRAMES * 1_000_000_000 // bitrate)
        # python-canopen sends from its own threads while a Notifier thread receives: one lock
        # keeps the ports to one thread at a time.
        self._lock = threading.Lock()
        #: Frames received from others (after skipping this endpoint's own).
        self.received = 0
        #: Frames sent.
        self.sent = 0
        #: Samples that were not a classic CAN frame (a peer's malformed sample), skipped.
        self.dropped = 0
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        try:
            self._node = (
                iox2.NodeBuilder.new()
                .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
                .create(iox2.ServiceType.Ipc)
            )
            # Dead processes keep their slots until someone cleans up: do it before taking ours.
            self._node.try_cleanup_dead_nodes()
            service = (
                self._node.service_builder(iox2.ServiceName.new(service_name(name)))
                .publish_subscribe(CanSample)
                .max_publishers(MAX_ENDPOINTS)
                .max_subscribers(MAX_ENDPOINTS)
                .max_nodes(MAX_NODES)
                .history_size(0)
                .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
                .enable_safe_overflow(True)
                .open_or_create()
            )
            self._subscriber = service.subscriber_builder().buffer_size(SUBSCRIBER_BUFFER).create()
            self._publisher = service.publisher_builder().create()
        except Exception as e:  # iceoryx2's errors have no common base class
            raise can.CanInitializationError(f"virtual bus vbus:{name}: {e!r}") from e
        self._service = service
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    # ---- receiving ------------------------------------------------------------------------

    def _take(self) -> Optional[can.Message]:
        """The next frame of another endpoint, or ``None`` when none is waiting."""
        while True:
            with self._lock:
                sample = self._subscriber.receive()
                if sample is None:
                    return None
                s = CanSample()
                ctypes.memmove(ctypes.byref(s), sample.payload_ptr, ctypes.sizeof(s))
                sample.delete()
            if s.sender == self._sender:
                continue
            if s.can_id & CAN_ERR_FLAG or s.len > 8:
                self.dropped += 1
                continue
            extended = bool(s.can_id & CAN_EFF_FLAG)
            remote = bool(s.can_id & CAN_RTR_FLAG)
            self.received += 1
            return can.Message(
                timestamp=(s.timestamp_ns + self.wall_offset_ns) / 1e9,
                arbitration_id=s.can_id & (0x1FFF_FFFF if extended else 0x7FF),
                is_extended_id=extended,
                is_remote_frame=remote,
                dlc=s.len,
                data=None if remote else bytes(s.data[: s.len]),
                channel=self.bus_name,
                is_rx=True,
            )

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[can.Message], bool]:
        deadline = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while True:
            msg = self._take()
            if msg is not None:
                return msg, False
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                return None, False
            # No event service on this bus (keeps senders cheap): look again at a fine interval.
            time.sleep(POLL_INTERVAL if deadline is None else min(POLL_INTERVAL, deadline - now))

    # ---- sending --------------------------------------------------------------------------

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        if msg.is_error_frame:
            raise can.CanOperationError("vbus carries no error frames")
        if msg.is_fd:
            raise can.CanOperationError("vbus is classic CAN: CAN FD frames are refused")
        limit = 0x1FFF_FFFF if msg.is_extended_id else 0x7FF
        if not 0 <= msg.arbitration_id <= limit:
            raise can.CanOperationError(
                f"identifier 0x{msg.arbitration_id:X} is outside 0 to 0x{limit:X} "
                f"({'extended' if msg.is_extended_id else 'standard'})"
            )
        dlc = msg.dlc
        if not 0 <= dlc <= 8 or (not msg.is_remote_frame and len(msg.data) > 8):
            raise can.CanOperationError(f"data length {dlc}: classic CAN carries 0 to 8 bytes")
        data = b"" if msg.is_remote_frame else bytes(msg.data[:dlc])
        duration = frame_duration_ns(msg.is_extended_id, msg.is_remote_frame, dlc, self.bitrate)
        deadline = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while True:
            with self._lock:
                now = _monotonic_ns()
                end = completion_time_ns(now, self._tx_end, duration, self._max_backlog)
                if end is not None:
                    s = CanSample()
                    s.sender = self._sender
                    s.timestamp_ns = end
                    s.can_id = (
                        msg.arbitration_id
                        | (CAN_EFF_FLAG if msg.is_extended_id else 0)
                        | (CAN_RTR_FLAG if msg.is_remote_frame else 0)
                    )
                    s.len = dlc
                    for i, b in enumerate(data):
                        s.data[i] = b
                    try:
                        self._publisher.send_copy(s)
                    except Exception as e:
                        raise can.CanOperationError(f"vbus:{self.bus_name}: sending failed: {e!r}") from e
                    self._tx_end = end
                    self.sent += 1
                    return
                # The transmit queue is full: wait until the backlog is back under its limit.
                wait = (self._tx_end - self._max_backlog - now) / 1e9
            if deadline is not None and time.monotonic() + wait > deadline:
                raise can.CanOperationError(
                    f"vbus:{self.bus_name}: transmit queue full ({TX_BACKLOG_FRAMES} frames of backlog)"
                )
            time.sleep(max(wait, POLL_INTERVAL))

    # ---- the rest -------------------------------------------------------------------------

    def shutdown(self) -> None:
        super().shutdown()
        with self._lock:
            for port in ("_publisher", "_subscriber"):
                p = getattr(self, port, None)
                if p is not None:
                    p.delete()
                    setattr(self, port, None)
            self._service = None
            self._node = None

    @staticmethod
    def _detect_available_configs() -> list:
        # Buses exist while an endpoint holds them; there is no list to offer without opening one.
        return []
