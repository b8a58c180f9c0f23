"""``graphslam info BAG``: the topics of a ROS bag, with message type, count and rate."""

from __future__ import annotations

import argparse

from graphslam.cli.common import add_command, add_topics_option, path_arg, warn
from slamcore.errors import ConfigError


def register(sub) -> None:
    p = add_command(
        sub,
        "info",
        cmd_info,
        help="list the topics of a ROS bag (type, messages, rate)",
        description="List every topic of a ROS 1 .bag file or a ROS 2 bag folder (sqlite3 or "
        "mcap) in one table: message type, message count and mean rate (Hz, from "
        "the record times), and which topics --dataset BAG would read. Needs the "
        'rosbags package: pip install ".[bags]".',
    )
    p.add_argument("bag", type=path_arg, metavar="BAG", help="a .bag file or a ROS 2 bag folder")
    add_topics_option(p, "as for graphslam run: check that these names pick the topics")


def cmd_info(args: argparse.Namespace) -> int:
    from graphslam.sources.spatial.rosbag import bag_topics, chosen_roles, parse_topics

    parse_topics(args.topics)  # a misspelt role is said before every message is read
    topics = bag_topics(args.bag)
    print(format_topics(topics))
    for t in topics:
        if t.count != t.stated_count:  # a ROS 2 bag's metadata.yaml edited or left stale
            warn(f"{args.bag}: {t.name}: the bag states {t.stated_count} messages, it holds {t.count}")
    roles = chosen_roles(args.bag, topics, args.topics)
    if args.topics is not None and not isinstance(roles, dict):
        # the listing is printed; the check the --topics asked for failed: a script sees it
        # (the reason may name the flag itself: "--topics image=/x: no such topic"), once
        prefix = f"--topics {args.topics}: "
        raise ConfigError(roles if roles.startswith("--topics ") else prefix + roles)
    print(
        "read by --dataset: "
        + (
            ", ".join(f"{r} {t}" for r, t in roles.items())
            if isinstance(roles, dict)
            else f"nothing ({roles})"
        )
    )
    return 0


def format_topics(topics) -> str:
    """One row per topic: name, type, messages, rate."""
    rows = [("topic", "type", "messages", "rate [Hz]")]
    rows += [
        (t.name, t.msgtype, str(t.count), "n/a" if t.rate_hz is None else f"{t.rate_hz:.2f}") for t in topics
    ]
    widths = [max(len(r[c]) for r in rows) for c in range(4)]
    lines = [
        f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:>{widths[2]}}  {r[3]:>{widths[3]}}" for r in rows
    ]
    return "\n".join(lines)
