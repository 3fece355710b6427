#!/usr/bin/env python3
"""Connects to a running motion coordinator over iceoryx2, prints its axes, sends one command
and prints the reply.

    pip install iceoryx2==0.10.0
    python3 example_watch_and_command.py [--prefix motion] [--axis 0] [--timeout 5]

The command is ``enable`` for ``--axis`` (``--all`` for every axis). Exit status: 0 when the
command latched, 3 when the coordinator refused it, 2 when the contract does not match the
coordinator's, 1 when there is no coordinator or it did not answer in time.
"""

import argparse
import ctypes
import os
import sys
import time

import iceoryx2 as iox2

import motion_shm as ms

POLL = iox2.Duration.from_millis(5)


def open_services(node, prefix):
    """The state subscriber and the command client; exits with a message when refused."""
    names = ms.service_names(prefix)
    try:
        state = (
            node.service_builder(iox2.ServiceName.new(names["state"]))
            .publish_subscribe(ms.MachineState)
            .open()
        )
        command = (
            node.service_builder(iox2.ServiceName.new(names["command"]))
            .request_response(ms.CommandRequest, ms.CommandReply)
            .open()
        )
    except (iox2.PublishSubscribeOpenError, iox2.RequestResponseOpenError) as e:
        # iceoryx2 compares type names (which carry the layout hash), sizes and alignments.
        if "Incompatible" in repr(e):
            print(
                f"error: the coordinator at '{prefix}' uses another contract version than "
                f"this client ({ms.MACHINE_STATE_TYPE_NAME}): {e!r}",
                file=sys.stderr,
            )
            sys.exit(2)
        print(f"error: no coordinator at '{prefix}': {e!r}", file=sys.stderr)
        sys.exit(1)
    return state.subscriber_builder().create(), command.client_builder().create()


def wait_state(node, subscriber, timeout_s):
    """A copy of the newest state sample, waiting up to ``timeout_s``; ``None`` on timeout."""
    deadline = time.monotonic() + timeout_s
    latest = None
    while latest is None and time.monotonic() < deadline:
        # Drain what is queued: only the newest sample matters.
        while True:
            sample = subscriber.receive()
            if sample is None:
                break
            latest = ms.MachineState()
            # Copy out of shared memory so the sample can be released at once.
            ctypes.memmove(ctypes.byref(latest), sample.payload_ptr, ctypes.sizeof(latest))
            sample.delete()
        if latest is None:
            node.wait(POLL)
    return latest


def print_state(state):
    """The machine's header line and one line per valid axis and group."""
    print(
        f"cycle {state.cycle}: {state.axis_count} axes, {state.group_count} groups, "
        f"inputs 0x{state.inputs:08x}{' (virtual time)' if state.virtual_time else ''}"
    )
    for i, axis in enumerate(state.valid_axes()):
        unit = axis.unit_str()
        print(
            f"  axis {i} {axis.name_str()}: {axis.state_name()} mode {axis.mode_name()} "
            f"at {ms.format_micro(axis.position)} {unit} "
            f"(setpoint {ms.format_micro(axis.setpoint)}) flags {axis.flag_names()} "
            f"fault {axis.fault_name()}"
        )
    for i, group in enumerate(state.valid_groups()):
        print(
            f"  group {i} {group.name_str()}: axes {group.member_axes()} "
            f"chain {ms.enum_name(ms.ChainState, group.chain_state)} "
            f"record {group.record} override {group.override_percent} %"
        )


def send_command(node, client, request, timeout_s):
    """Sends ``request``; the reply (a copy) or ``None`` when none came within ``timeout_s``."""
    pending = client.send_copy(request)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        response = pending.receive()
        if response is not None:
            reply = ms.CommandReply()
            ctypes.memmove(ctypes.byref(reply), response.payload_ptr, ctypes.sizeof(reply))
            response.delete()
            return reply
        node.wait(POLL)
    return None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", default=ms.DEFAULT_PREFIX, help="service name prefix")
    parser.add_argument("--axis", type=int, default=0, help="the axis to enable")
    parser.add_argument("--all", action="store_true", help="enable every axis instead")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to wait")
    args = parser.parse_args()

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    subscriber, client = open_services(node, args.prefix)

    state = wait_state(node, subscriber, args.timeout)
    if state is None:
        print(f"error: no state from '{args.prefix}' within {args.timeout} s", file=sys.stderr)
        return 1
    print(
        f"connected to '{args.prefix}' (layout v{state.version}, "
        f"hash 0x{state.layout_hash:08x})"
    )
    if not state.layout_matches():
        print("warning: the state's version or layout hash differs from this module's")
    print_state(state)

    request = ms.CommandRequest.enable() if args.all else ms.CommandRequest.enable(axis=args.axis)
    request.tag = os.getpid()
    what = "all axes" if args.all else f"axis {args.axis}"
    reply = send_command(node, client, request, args.timeout)
    if reply is None:
        print(f"error: no reply to 'enable {what}' within {args.timeout} s", file=sys.stderr)
        return 1
    if reply.tag != request.tag:
        print(f"warning: reply tag {reply.tag} is not the request's {request.tag}")
    print(f"command ENABLE {what} (tag {request.tag}): {reply.describe()}")
    return 0 if reply.latched() else 3


if __name__ == "__main__":
    try:
        sys.exit(main())
    except iox2.NodeWaitFailure:
        # SIGINT/SIGTERM while waiting.
        sys.exit(130)
