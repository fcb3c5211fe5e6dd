"""A userspace Ethernet switch with seeded delay, jitter and loss (netem's job, without sch_netem).

Run inside the switch namespace of :mod:`helpers.netlab`, one argument per port (the
switch-side end of a veth pair)::

    python netswitch.py --seed 0 p-sim p-ekf p-pp p-obs

It reads frames from each port (AF_PACKET, promiscuous), learns source MACs and forwards each
frame to the port of its destination (or floods it). Frames that *enter* an impaired port are
dropped with probability ``loss`` or held for ``delay + uniform(-jitter, jitter)`` seconds, so
every frame between two impaired hosts is impaired once, as with ``tc qdisc ... netem`` on each
host's egress. Commands on stdin, one per line, each answered ``ok`` on stdout:

    impair <delay_s> <jitter_s> <loss> <port> [<port> ...]   (0 0 0 clears)
    stats                                                    (one JSON line, then ok)
    quit

``ready`` is printed once every port is open. ``--tx-checksum-off eth0``, run in a host
namespace, makes that host's kernel fill in its checksums (see :func:`tx_checksum_off`).
Kernels without ``CONFIG_NET_SCH_NETEM`` (this machine's) cannot delay packets in tc; the
switch can, and its loss and jitter are seeded.
"""

from __future__ import annotations

import argparse
import ctypes
import fcntl
import heapq
import json
import os
import random
import select
import socket
import struct
import sys
import time

ETH_P_ALL = 0x0003
SOL_PACKET = 263
PACKET_ADD_MEMBERSHIP = 1
PACKET_MR_PROMISC = 1
PACKET_OUTGOING = 4
SIOCETHTOOL = 0x8946
ETHTOOL_STXCSUM = 0x17


def open_port(name: str) -> socket.socket:
    """A raw socket on interface ``name`` that sees every frame arriving there."""
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.bind((name, 0))
    mreq = struct.pack("iHH8s", socket.if_nametoindex(name), PACKET_MR_PROMISC, 0, b"")
    s.setsockopt(SOL_PACKET, PACKET_ADD_MEMBERSHIP, mreq)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    s.setblocking(False)
    return s


def tx_checksum_off(name: str) -> None:
    """Have the kernel checksum what ``name`` sends (``ethtool -K name tx off``).

    A veth leaves checksums to the receiver's kernel (CHECKSUM_PARTIAL); a frame read from a
    packet socket and sent on again would arrive with a wrong one and be dropped.
    """
    value = ctypes.create_string_buffer(struct.pack("II", ETHTOOL_STXCSUM, 0))
    request = struct.pack("16sP", name.encode(), ctypes.addressof(value))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        fcntl.ioctl(s.fileno(), SIOCETHTOOL, request)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tx-checksum-off", metavar="IFACE",
                        help="only turn off IFACE's checksum offload (run in the host namespace), then exit")
    parser.add_argument("ports", nargs="*")
    args = parser.parse_args(argv)
    if args.tx_checksum_off:
        tx_checksum_off(args.tx_checksum_off)
        return 0
    rng = random.Random(args.seed)
    ports = {name: open_port(name) for name in args.ports}
    by_fd = {s.fileno(): name for name, s in ports.items()}
    impair = {name: (0.0, 0.0, 0.0) for name in ports}  # delay s, jitter s, loss probability
    stats = {name: {"in": 0, "lost": 0, "delayed": 0, "out": 0, "send_errors": 0} for name in ports}
    macs: dict[bytes, str] = {}
    held: list[tuple[float, int, str, bytes]] = []  # (release time, sequence, ingress port, frame)
    seq = 0
    pending = b""
    stdin = sys.stdin.fileno()
    print("ready", flush=True)

    def forward(ingress: str, frame: bytes) -> None:
        dst = macs.get(frame[0:6])
        targets = [dst] if dst is not None and dst != ingress else [p for p in ports if p != ingress]
        for p in targets:
            try:
                ports[p].send(frame)
                stats[p]["out"] += 1
            except OSError:  # the link is down (ip link set down on the host side)
                stats[p]["send_errors"] += 1

    while True:
        now = time.monotonic()
        while held and held[0][0] <= now:
            _, _, ingress, frame = heapq.heappop(held)
            forward(ingress, frame)
        timeout = max(0.0, held[0][0] - now) if held else 0.5
        readable, _, _ = select.select([stdin, *by_fd], [], [], timeout)
        for fd in readable:
            if fd == stdin:
                chunk = os.read(stdin, 4096)
                if not chunk:  # the controller is gone
                    return 0
                pending += chunk
                while b"\n" in pending:
                    line, pending = pending.split(b"\n", 1)
                    words = line.decode().split()
                    if words and words[0] == "quit":
                        return 0
                    if words and words[0] == "impair":
                        delay, jitter, loss = (float(w) for w in words[1:4])
                        for p in words[4:]:
                            impair[p] = (delay, jitter, loss)
                    elif words and words[0] == "stats":
                        print(json.dumps(stats), flush=True)
                    print("ok", flush=True)
                continue
            name = by_fd[fd]
            for _ in range(256):  # drain what is queued on this port
                try:
                    frame, addr = ports[name].recvfrom(65536)
                except BlockingIOError:
                    break
                if addr[2] == PACKET_OUTGOING:  # our own send on this port
                    continue
                stats[name]["in"] += 1
                macs[frame[6:12]] = name
                delay, jitter, loss = impair[name]
                if loss and rng.random() < loss:
                    stats[name]["lost"] += 1
                    continue
                if delay or jitter:
                    stats[name]["delayed"] += 1
                    seq += 1
                    heapq.heappush(held, (time.monotonic() + max(0.0, delay + rng.uniform(-jitter, jitter)),
                                          seq, name, frame))
                else:
                    forward(name, frame)


if __name__ == "__main__":
    sys.exit(main())
