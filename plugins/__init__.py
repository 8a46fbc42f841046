"""First-party plugins of modalctl, installed as ``modalctl.plugins`` and registered through the
``modalctl`` entry point group exactly as a third-party plugin would be."""
