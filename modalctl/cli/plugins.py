"""``modalctl plugins``: the installed plugins, the hooks each implements, and the shape generators
with their parameters."""

from __future__ import annotations

import json

NAME, HELP = "plugins", "list installed plugins and shape generators"


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true")


def run(args) -> int:
    from modalctl.plugin.manager import plugin_table, shape_generators

    plugins, shapes = plugin_table(), shape_generators()
    if args.json:
        shape_rows = {n: {"summary": g.summary, "params": [{"name": p.name, "unit": p.unit, "default": p.default,
                                                             "required": p.required, "doc": p.doc}
                                                            for p in g.params]} for n, g in shapes.items()}
        print(json.dumps({"plugins": plugins, "shapes": shape_rows}, indent=2, default=str))
        return 0
    print("plugins:")
    for row in plugins:
        print(f"  {row['name']:28s} {row['distribution']:20s} hooks: {', '.join(row['hooks']) or '-'}")
    print("shapes:")
    for name, g in shapes.items():
        params = ", ".join(f"{p.name}[{p.unit}]" + ("*" if p.required else "") for p in g.params)
        print(f"  {name:10s} {g.summary}\n  {'':10s} params: {params}   (* required)")
    return 0
