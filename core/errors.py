"""Errors raised by the core, with messages an artist can act on. No bpy."""


class BakeError(Exception):
    """A problem the user can fix (bad input, missing dependency); the message says what and where."""


class BakeCancelled(BakeError):
    """The user cancelled the bake; nothing was written."""


class DependencyMissing(BakeError):
    """A compiled dependency (embreex, xatlas, OpenEXR) could not be imported."""
