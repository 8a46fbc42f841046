"""Plugins: first-party ones load through entry points, third-party ones plug in, hooks are documented."""

import re
from pathlib import Path

import pluggy
import pytest

from modalctl.model.shape import Param, Shape
from modalctl.plugin import spec as hookspecs
from modalctl.plugin.manager import (
    ENTRY_POINT_GROUP,
    PluginError,
    get_shape,
    plugin_manager,
    plugin_table,
    shape_generators,
)
from modalctl.plugin.spec import hookimpl

DOCS = Path(__file__).resolve().parents[1] / "docs" / "plugins.md"


def hook_names():
    return [name for name in dir(hookspecs) if name.startswith("modalctl_")]


@pytest.mark.parametrize("hook", hook_names())
def test_every_hook_is_documented(hook):
    """Like datasette's test: each hook spec has a section in docs/plugins.md."""
    assert re.search(rf"^#+ .*\b{hook}\b", DOCS.read_text(), re.MULTILINE), f"{hook} is not documented"


def test_first_party_plugin_loads_through_entry_point():
    from importlib.metadata import entry_points

    names = {ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}
    assert "modalctl.plugins.shapes" in names
    assert {"sinc", "bump", "square", "trapezoid", "gaussian", "sum", "array"} <= set(shape_generators())
    assert any(row["hooks"] == ["modalctl_shapes"] for row in plugin_table())


class Ring:
    name = "ring"
    summary = "a ring of given radius"
    params = (Param("radius", "m", required=True),)

    def generate(self, grid, *, radius):
        r = abs(grid.x)
        return Shape((abs(r - radius) < 0.002).astype(float), abs(r - radius) < 0.002)


class ThirdParty:
    @hookimpl
    def modalctl_shapes(self):
        return [Ring()]


def _manager_with(*plugins):
    manager = pluggy.PluginManager(ENTRY_POINT_GROUP)
    manager.add_hookspecs(hookspecs)
    for plugin in plugins:
        manager.register(plugin)
    for name, plugin in plugin_manager().list_name_plugin():
        manager.register(plugin, name)
    return manager


def test_third_party_shape_plugs_in():
    manager = _manager_with(ThirdParty())
    assert "ring" in shape_generators(manager)
    assert get_shape("ring", manager).summary.startswith("a ring")


def test_duplicate_names_are_refused():
    class Clash:
        @hookimpl
        def modalctl_shapes(self):
            ring = Ring()
            ring.name = "sinc"
            return [ring]

    with pytest.raises(PluginError, match="two plugins"):
        shape_generators(_manager_with(Clash()))


def test_unknown_shape_lists_installed():
    with pytest.raises(PluginError, match="unknown shape .*installed: .*sinc"):
        get_shape("no-such-shape")
