"""First-party plugins of modalctl, registered through the ``modalctl`` entry point group exactly as a
third-party plugin would be: shapes, transports, identifiers and trackers, controllers."""
