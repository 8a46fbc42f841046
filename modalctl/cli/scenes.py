"""``modalctl scenes``: the named scenes, one line each (or JSON)."""

from __future__ import annotations

import json

NAME, HELP = "scenes", "list the named scenes"


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true")


def run(args) -> int:
    from modalctl.model.scenes import SCENES

    if args.json:
        print(json.dumps({name: s.summary for name, s in SCENES.items()}, indent=2))
    else:
        for name, s in SCENES.items():
            print(f"{name:18s} {s.summary}")
    return 0
