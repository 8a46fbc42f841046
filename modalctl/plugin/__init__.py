"""The plugin system (pluggy), laid out as tox's: hook specifications (:mod:`.spec`) and the manager
that loads every plugin registered under the ``modalctl`` entry point group (:mod:`.manager`).

First-party plugins live in :mod:`modalctl.plugins` and register exactly as a third party's would.
Imports only :mod:`modalctl.model` (for the shape contract).
"""
