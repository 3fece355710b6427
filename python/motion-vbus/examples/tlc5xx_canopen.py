"""Drive a simulated TLC5xx on the virtual bus with python-canopen, as a test engineer would.

Start the drive first, then this script (any bus name; the TLC5xx's node-ID 5 here):

    target/debug/drive-sim --device tlc5xx --bus vbus:bench --node 5
    target/debug/drive-sim --write-eds tlc5xx > tlc5xx.eds
    python3 python/motion-vbus/examples/tlc5xx_canopen.py --bus bench --node 5 --eds tlc5xx.eds

It takes the node through NMT (reset, pre-operational, operational), SDO uploads and downloads
(expedited and segmented), remaps TPDO1 and RPDO1 and reads the mapping back, and makes a
CiA 402 profile-position move with the setpoints in RPDO1 and the statusword and position in
TPDO1 at every SYNC. It also reads every readable object of the EDS by SDO and compares it with
the EDS (``--check-eds``, for each device given; see ``--help``). Every step prints one line;
the script ends with ``PASSED`` (exit 0) or the first failure (exit 1). ``tests/tests/python_can.rs``
runs it against drive-sim processes.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time

import can
import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

# Statusword bits (CiA 402).
READY_TO_SWITCH_ON = 0x0001
SWITCHED_ON = 0x0002
OPERATION_ENABLED = 0x0004
FAULT = 0x0008
TARGET_REACHED = 0x0400
SETPOINT_ACKNOWLEDGE = 0x1000


class Failed(Exception):
    """A step did not do what it should."""


def step(text: str) -> None:
    print(f"ok: {text}", flush=True)


def check(cond: bool, text: str) -> None:
    if not cond:
        raise Failed(text)


def wait_for(what: str, cond, timeout: float = 5.0):
    """Polls ``cond`` until it returns something true; fails with ``what`` after ``timeout``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.005)
    raise Failed(f"{what}: not within {timeout} s")


def variables(od):
    """Every variable of an object dictionary, sub-indices included."""
    for obj in od.values():
        if isinstance(obj, ODVariable):
            yield obj
        elif isinstance(obj, (ODRecord, ODArray)):
            yield from obj.values()


def comparable(v):
    return v.rstrip(" \x00") if isinstance(v, str) else v


def check_eds(network: canopen.Network, node_id: int, eds: str) -> None:
    """python-canopen imports the EDS; an SDO read of each readable object agrees with it."""
    node = canopen.RemoteNode(node_id, eds)
    network.add_node(node)
    name = node.object_dictionary.device_information.product_name
    count = 0
    differ = []
    for v in variables(node.object_dictionary):
        if not v.readable:
            continue
        raw = node.sdo.upload(v.index, v.subindex)
        value = v.decode_raw(raw)
        count += 1
        if comparable(value) != comparable(v.default):
            differ.append(f"{v.index:04X}h:{v.subindex:02X} {v.name}: read {value!r}, EDS {v.default!r}")
    check(not differ, f"{name} node {node_id}: {len(differ)} of {count} SDO reads differ from its EDS:\n  " + "\n  ".join(differ))
    step(f"{name} node {node_id}: python-canopen imported its EDS; all {count} readable objects read by SDO agree with it")
    del network[node_id]


def reset_and_wait(network: canopen.Network, node: canopen.RemoteNode) -> None:
    """NMT reset communication, then the boot-up. The TLC5xx announces it the legacy way (an
    empty frame on its EMCY COB-ID 80h+node, manual §3.5), which python-canopen's
    ``wait_for_bootup`` (700h+node) does not see: listen for either."""
    booted = threading.Event()

    class BootUp(can.Listener):
        # A listener of its own on the bus: python-canopen's EMCY consumer, which raises on the
        # empty frame, would keep a subscriber after it from seeing the frame.
        def on_message_received(self, m: can.Message) -> None:
            if (m.arbitration_id == 0x700 + node.id and bytes(m.data[:1]) == b"\x00") or (
                m.arbitration_id == 0x80 + node.id and m.dlc == 0
            ):
                booted.set()

    listener = BootUp()
    network.notifier.add_listener(listener)
    # python-canopen's EMCY consumer cannot read an empty EMCY and logs it: expected here.
    logging.getLogger("canopen").setLevel(logging.CRITICAL)
    node.nmt.state = "RESET COMMUNICATION"
    check(booted.wait(5.0), "no boot-up within 5 s of NMT reset communication")
    logging.getLogger("canopen").setLevel(logging.WARNING)
    network.notifier.remove_listener(listener)
    step(f"NMT reset communication: boot-up seen, node {node.id} pre-operational")


def sdo_transfers(node: canopen.RemoteNode) -> None:
    device_type = node.sdo.upload(0x1000, 0)
    check(len(device_type) == 4 and int.from_bytes(device_type, "little") & 0xFFFF == 402,
          f"1000h device type {device_type.hex()}: not a CiA 402 drive")
    step(f"SDO upload, expedited: 1000h device type {int.from_bytes(device_type, 'little'):08X}h")
    name = node.sdo.upload(0x1008, 0)
    check(len(name) > 4, f"1008h {name!r}: expected a segmented upload of more than 4 bytes")
    step(f"SDO upload, segmented: 1008h device name {name.decode().rstrip()!r} ({len(name)} bytes)")
    node.sdo.download(0x6081, 0, (1500).to_bytes(4, "little"))
    check(int.from_bytes(node.sdo.upload(0x6081, 0), "little") == 1500, "6081h after an expedited download")
    step("SDO download, expedited: 6081h profile velocity 1500, read back")
    node.sdo.download(0x6083, 0, (4000).to_bytes(4, "little"), force_segment=True)
    node.sdo.download(0x6084, 0, (4000).to_bytes(4, "little"), force_segment=True)
    check(int.from_bytes(node.sdo.upload(0x6083, 0), "little") == 4000, "6083h after a segmented download")
    step("SDO download, segmented: 6083h and 6084h acceleration and deceleration 4000, read back")
    try:
        node.sdo.download(0x1000, 0, b"\x00\x00\x00\x00")
        raise Failed("a download to the read-only 1000h was accepted")
    except canopen.SdoAbortedError as e:
        step(f"SDO download to read-only 1000h refused: abort {e.code:08X}h")


def remap(node: canopen.RemoteNode) -> None:
    node.tpdo.read()
    node.rpdo.read()
    tpdo, rpdo = node.tpdo[1], node.rpdo[1]
    tpdo.clear()
    tpdo.add_variable(0x6041)
    tpdo.add_variable(0x6064)
    tpdo.trans_type = 1
    tpdo.enabled = True
    rpdo.clear()
    rpdo.add_variable(0x6040)
    rpdo.add_variable(0x607A)
    rpdo.trans_type = 1
    rpdo.enabled = True
    tpdo.save()
    rpdo.save()
    # Read back from the drive into fresh maps, not what python-canopen remembers.
    fresh = canopen.RemoteNode(node.id, node.object_dictionary)
    fresh.associate_network(node.network)
    fresh.tpdo.read()
    fresh.rpdo.read()
    got_t = [(v.index, v.subindex) for v in fresh.tpdo[1].map]
    got_r = [(v.index, v.subindex) for v in fresh.rpdo[1].map]
    check(got_t == [(0x6041, 0), (0x6064, 0)], f"TPDO1 read back as {got_t}")
    check(got_r == [(0x6040, 0), (0x607A, 0)], f"RPDO1 read back as {got_r}")
    check(fresh.tpdo[1].trans_type == 1 and fresh.tpdo[1].enabled, "TPDO1 not synchronous and enabled")
    raw = int.from_bytes(node.sdo.upload(0x1A00, 1), "little")
    check(raw == 0x6041_0010, f"1A00h:01 reads {raw:08X}h")
    step("PDO remapping: TPDO1 = statusword + position actual, RPDO1 = controlword + target position, synchronous; read back from the drive")


def move(network: canopen.Network, node: canopen.RemoteNode, target: int) -> None:
    node.sdo.download(0x6060, 0, (1).to_bytes(1, "little", signed=True))
    check(int.from_bytes(node.sdo.upload(0x6061, 0), "little", signed=True) == 1, "6061h is not profile position")
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    tpdo, rpdo = node.tpdo[1], node.rpdo[1]
    status = lambda: tpdo["statusword"].raw if tpdo.is_received else None  # noqa: E731

    def command(word: int, position: int | None = None) -> None:
        rpdo["controlword"].raw = word
        if position is not None:
            rpdo["target position"].raw = position
        rpdo.transmit()

    wait_for("a TPDO1 at SYNC", lambda: tpdo.wait_for_reception(1.0) is not None)
    step(f"NMT operational, SYNC every 10 ms: TPDO1 arrives (statusword {status():04X}h)")
    for word, mask, want, name in [
        (0x06, 0x6F, 0x21, "Ready to switch on"),
        (0x07, 0x6F, 0x23, "Switched on"),
        (0x0F, 0x6F, 0x27, "Operation enabled"),
    ]:
        command(word, tpdo["position actual value"].raw)
        wait_for(f"{name} after controlword {word:04X}h (statusword {status():04X}h)",
                 lambda: (status() & mask) == want)
    step("CiA 402 state machine: Ready to switch on, Switched on, Operation enabled (controlword in RPDO1)")
    start = tpdo["position actual value"].raw
    command(0x1F, target)  # new setpoint, absolute
    wait_for("setpoint acknowledge", lambda: status() & SETPOINT_ACKNOWLEDGE)
    command(0x0F, target)
    moving = wait_for("the position to change", lambda: tpdo["position actual value"].raw != start)
    wait_for(f"target reached at {target}", lambda: status() & TARGET_REACHED and not status() & SETPOINT_ACKNOWLEDGE, timeout=20.0)
    at = tpdo["position actual value"].raw
    check(abs(at - target) <= 2, f"stands at {at}, not {target}")
    check(not status() & FAULT, f"statusword {status():04X}h shows a fault")
    step(f"profile-position move from {start} to {target}: target reached, position actual {at}")
    command(0x06, target)
    wait_for("Ready to switch on again", lambda: (status() & 0x6F) == 0x21)
    network.sync.stop()
    node.nmt.state = "PRE-OPERATIONAL"
    step("disabled (controlword 0006h), SYNC stopped, NMT pre-operational")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bus", required=True, help="the virtual bus's name (vbus:NAME)")
    p.add_argument("--node", type=int, default=5, help="the TLC5xx's node-ID")
    p.add_argument("--eds", required=True, help="the TLC5xx's EDS (drive-sim --write-eds tlc5xx)")
    p.add_argument("--target", type=int, default=2000, help="the move's target position, user units")
    p.add_argument("--check-eds", nargs=2, action="append", default=[], metavar=("NODE", "EDS"),
                   help="also compare every readable object of the drive at NODE with EDS")
    p.add_argument("--log", help="write every frame received to this python-can log (.log: candump format)")
    args = p.parse_args()

    network = canopen.Network()
    network.connect(interface="vbus", channel=args.bus)
    logger = can.Logger(args.log) if args.log else None
    if logger is not None:
        network.notifier.add_listener(logger)
    step(f"python-can {can.__version__} and python-canopen {canopen.__version__} on vbus:{args.bus} ({network.bus.channel_info})")
    try:
        for node_id, eds in [(str(args.node), args.eds)] + args.check_eds:
            check_eds(network, int(node_id), eds)
        node = network.add_node(args.node, args.eds)
        reset_and_wait(network, node)
        sdo_transfers(node)
        remap(node)
        move(network, node, args.target)
    except (Failed, canopen.SdoAbortedError, canopen.SdoCommunicationError, can.CanError) as e:
        print(f"FAILED: {e}", flush=True)
        return 1
    finally:
        if logger is not None:
            network.notifier.remove_listener(logger)
            logger.stop()
        network.disconnect()
    print("PASSED", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
