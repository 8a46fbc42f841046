"""Draw modalctl's layers from its own imports: ``docs/architecture.png``.

    python tools/architecture.py     # writes docs/architecture.png and prints each package's imports

The layers are the import-linter contract in ``pyproject.toml`` (top to bottom, ``a | b`` for
siblings that do not import each other); the arrows are the imports grimp, import-linter's own
graph builder, finds in the code, gathered package to package, their width the number of
module-to-module imports. Every arrow points down: one that pointed up would break the contract,
and ``tests/test_architecture.py`` would fail. The foundations (``options``, ``units``) are
imported from every layer; their arrows are left out of the picture and counted in its legend.
"""

from __future__ import annotations

import sys
import tomllib
from collections import Counter
from pathlib import Path

import grimp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "modalctl"
FOUNDATIONS = ("options", "units")


def layers() -> list[list[str]]:
    """The contract's layers, top first, each a list of sibling packages."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    contract = next(c for c in config if c["type"] == "layers")
    return [[name.strip() for name in layer.split("|")] for layer in contract["layers"]]


def part_of(module: str) -> str:
    """The top-level package or module of ``modalctl`` a module belongs to."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def package_imports() -> Counter:
    """``{(importer part, imported part): number of module-to-module imports}`` within modalctl."""
    graph = grimp.build_graph(PACKAGE)
    counts: Counter = Counter()
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            a, b = part_of(module), part_of(imported)
            if a != b and PACKAGE not in (a, b):
                counts[a, b] += 1
    return counts


def lines_of(part: str) -> int:
    path = ROOT / PACKAGE / part
    files = sorted(path.rglob("*.py")) if path.is_dir() else [path.with_suffix(".py")]
    return sum(len(f.read_text().splitlines()) for f in files)


def draw(path: Path) -> Path:
    rows = layers()
    edges = package_imports()
    order = [part for row in rows for part in row]
    y = {}
    for level, row in enumerate(rows):
        for part in row:
            y[part] = -level
    x = {}
    for row in rows:
        for i, part in enumerate(row):
            x[part] = i * 2.3 - (len(row) - 1) * 1.15
    fig, ax = plt.subplots(figsize=(12, 0.62 * len(rows) + 1.6))
    colours = plt.get_cmap("tab10")
    side = {part: -1.0 if x[part] < 0 else 1.0 for part in order}  # a left sibling's arrows leave on the left
    upward = []
    for (a, b), n in sorted(edges.items(), key=lambda item: item[1]):
        if b in FOUNDATIONS or a not in y or b not in y:  # __main__ (python -m modalctl) is in no layer
            continue
        if y[a] < y[b]:
            upward.append((a, b))
        reach = y[a] - y[b]
        bend = (0.18 + 0.045 * abs(reach)) * side[a]
        start, end = (x[a] + side[a], y[a]), (x[b] + side[a], y[b])  # both on the importer's side
        colour = "#b22222" if (a, b) in upward else colours(order.index(a) % 10)
        ax.add_patch(FancyArrowPatch(start, end, connectionstyle=f"arc3,rad={-bend}", arrowstyle="-|>",
                                     mutation_scale=8, lw=0.4 + 0.25 * n ** 0.5, color=colour, alpha=0.6, zorder=1))
    for part in order:
        box = FancyBboxPatch((x[part] - 1.0, y[part] - 0.3), 2.0, 0.6, boxstyle="round,pad=0.02",
                             facecolor="#eef3f8" if part not in FOUNDATIONS else "#f4f4e8", edgecolor="#335",
                             lw=0.8, zorder=2)
        ax.add_patch(box)
        kind = "/" if (ROOT / PACKAGE / part).is_dir() else ".py"
        ax.text(x[part], y[part] + 0.06, f"{part}{kind}", ha="center", va="center", fontsize=10, weight="bold",
                zorder=3)
        ax.text(x[part], y[part] - 0.17, f"{lines_of(part):,} lines", ha="center", va="center", fontsize=7,
                color="#555", zorder=3)
    for level, row in enumerate(rows):
        if len(row) > 1:
            ax.text(0, -level + 0.42, "siblings: neither imports the other", fontsize=7, color="#777",
                    ha="center")
    into = sum(n for (a, b), n in edges.items() if b in FOUNDATIONS)
    ax.set_xlim(min(x.values()) - 1.3, max(x.values()) + 2.6)  # the widest row's boxes, and the arcs on the right
    ax.set_ylim(-len(rows) + 0.4, 0.8)
    ax.axis("off")
    ax.set_title("modalctl's layers, top to bottom: each arrow is a package importing another (coloured by the "
                 "importer;\nwidth: module-to-module imports); every arrow points down. Not drawn: the "
                 f"{into} imports of the foundations (options, units)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    if upward:
        raise SystemExit(f"imports that run upward: {upward}")
    return path


def main() -> None:
    path = draw(ROOT / "docs" / "architecture.png")
    edges = package_imports()
    for row in layers():
        for part in row:
            uses = sorted(b for (a, b) in edges if a == part)
            print(f"{part:12s} imports {', '.join(uses) or '-'}")
    print(f"wrote {path.relative_to(ROOT)}")


if __name__ == "__main__":
    sys.exit(main())
