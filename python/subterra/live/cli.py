"""``subterra node`` and ``subterra sil``: the live ROS 2 node and software in the loop."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from typing import Any

from subterra.errors import InputError

__all__ = ["register_cli"]


def register_cli(subparsers: argparse._SubParsersAction) -> None:
    """Adds ``node`` and ``sil``; their handlers are ``args.handler``."""
    from subterra.cli import int_in, nonempty, positive_float, seed_int, sim_seconds

    p = subparsers.add_parser("node", help="run live as a ROS 2 node over DDS (no ROS install needed; extra subterra[ros])",
                              description="Subscribes to the robot's sensors, odometry, goals and tf over ROS 2 DDS and publishes "
                                          "velocity commands, the path, the maps and diagnostics (docs/live.md).")
    p.add_argument("robot", choices=("ground", "drone"), help="ground: point clouds -> Navigator; drone: depth images -> Pilot")
    p.add_argument("--config", type=nonempty, default=None, help="node settings (TOML: topics, frames, QoS, rates, safety; configs/node.toml)")
    p.add_argument("--domain-id", type=int_in(0, 232), default=None, help="DDS domain (ROS_DOMAIN_ID; default from the config, 0)")
    p.add_argument("--use-sim-time", action="store_true", help="read ages against /clock (a simulator) instead of the wall clock")
    p.add_argument("--loopback", action="store_true", help="keep DDS on 127.0.0.1 (no traffic leaves this machine)")
    p.add_argument("--duration", type=positive_float, default=None, help="stop after this many wall seconds (default: until Ctrl-C)")
    p.add_argument("--stats", type=nonempty, default=None, help="write the node's counts (frames, drops, stops, compute time) to this JSON file at exit")
    p.add_argument("--mavlink", type=nonempty, default=None, metavar="CONNECTION",
                   help="also stream the commands to a PX4/ArduPilot autopilot as MAVLink velocity setpoints, e.g. "
                        "udpout:127.0.0.1:14540 (extra subterra[mavlink]); it never arms the vehicle")
    p.add_argument("--mavlink-frame", choices=("body", "local"), default="body", help="body: FLU -> MAV_FRAME_BODY_NED (default)")
    p.add_argument("--mavlink-baud", type=int_in(1200, 12_000_000), default=921600, help="serial rate for a serial --mavlink device")
    p.add_argument("--foxglove", type=nonempty, default=None, metavar="[HOST:]PORT",
                   help="serve a live view on Foxglove's WebSocket protocol (loopback unless HOST is given; extra subterra[viz])")
    p.set_defaults(handler=_node)

    s = subparsers.add_parser("sil", help="software in the loop: the simulator and `subterra node` as two processes over DDS",
                              description="Runs the simulator in this process and `subterra node` in another; they talk ROS 2 over "
                                          "DDS on the loopback interface, in lockstep. Writes metrics.json with the end-to-end latency.")
    s.add_argument("--robot", choices=("ground", "drone"), default="ground", help="ground (default, scenario mine) or drone (highbay)")
    s.add_argument("--scenario", default=None, help="ground: mine, slopes, rough, ledge, cave; drone: highbay")
    s.add_argument("--seed", type=seed_int, default=0, help="world and sensor noise seed (default 0)")
    s.add_argument("--out", type=nonempty, default="runs/sil", help="run folder (default runs/sil)")
    s.add_argument("--domain-id", type=int_in(0, 232), default=None, help="DDS domain (default: 100 + pid %% 100)")
    s.add_argument("--time-limit", type=sim_seconds, default=None, help="simulated seconds (default as drive/fly)")
    s.add_argument("--config", type=nonempty, default=None, help="the node's settings (TOML); the loop sets its domain, clock and sensor QoS")
    s.set_defaults(handler=_sil)


def _node(args: argparse.Namespace) -> int:
    from subterra.live.config import NodeConfig
    from subterra.live.node import make_node, write_stats

    config = NodeConfig.load(args.config) if args.config else NodeConfig()
    if args.stats:  # found out now, not after the run
        from pathlib import Path

        stats = Path(args.stats)
        if stats.is_dir() or (stats.exists() and not stats.is_file()) or not stats.parent.is_dir():
            raise InputError(f"argument --stats must be a file in an existing folder, got {args.stats}")
    changes: dict[str, Any] = {}
    if args.domain_id is not None:
        changes["domain_id"] = args.domain_id
    if args.use_sim_time:
        changes["use_sim_time"] = True
    if changes:
        config = config.replace(node=changes)
    bridge = None
    if args.mavlink:
        from subterra.live.mavlink import MavlinkBridge

        bridge = MavlinkBridge(args.mavlink, frame=args.mavlink_frame, baud=args.mavlink_baud)
    view = None
    if args.foxglove:
        from subterra.live.view import FoxgloveView, parse_address

        host, port = parse_address(args.foxglove)
        view = FoxgloveView(host, port)
        print(f"subterra node {args.robot}: live view on {view.url} (open it in Foxglove)", file=sys.stderr, flush=True)
    node = make_node(args.robot, config, loopback=args.loopback, mavlink=bridge, view=view)
    previous = {sig: signal.signal(sig, lambda *_: node.stop()) for sig in (signal.SIGINT, signal.SIGTERM)}
    print(f"subterra node {args.robot}: DDS domain {config.node.domain_id}, commands on {config.topics.cmd_vel}"
          f"{' (loopback only)' if args.loopback else ''}", file=sys.stderr, flush=True)
    try:
        stats = node.run(duration_s=args.duration)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        node.close()
        if bridge is not None:
            bridge.close()
        if view is not None:
            view.close()
    if args.stats:
        write_stats(stats, args.stats)
    s = stats.summary()
    print(f"subterra node {args.robot}: {s['frames_processed']} frames, {s['frames_dropped']} dropped, {s['commands']} commands, "
          f"stops {json.dumps(s['stops'])}", file=sys.stderr)
    return 0


def _sil(args: argparse.Namespace) -> int:
    from subterra.live.config import NodeConfig
    from subterra.live.sil import sil

    config = NodeConfig.load(args.config) if args.config else None
    m = sil(args.robot, args.scenario, seed=args.seed, out=args.out, domain_id=args.domain_id, time_limit_s=args.time_limit,
            node_config=config, progress=True)
    outcome = "reached the goal" if m["success"] else f"failed ({m['failure']})"
    print(f"sil {m['robot']} {m['scenario']} seed {m['seed']}: {outcome} in {m['time_s']:.1f} s simulated, "
          f"path {m['path_length_m']:.1f} m; latency sensor -> command median {m['latency_ms_median']:.1f} ms, "
          f"p99 {m['latency_ms_p99']:.1f} ms; {m['commands_missed']} commands missed")
    print(f"  {args.out}/metrics.json, trajectory.csv, node.log")
    return 0 if m["success"] else 3
