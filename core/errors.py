"""Errors raised by the core, with messages an artist can act on. No bpy."""


class BakeError(Exception):
    """A problem the user can fix (bad input, missing dependency); the message says what and where."""


class BakeCancelled(BakeError):
    """The user cancelled the bake; nothing was written."""


class InwardFacesRefused(BakeError):
    """Faces Pointing In = Refuse, and some receivers have such faces: `messages`, one per object
    (`core.bakepoints.inward`), are also the error's lines."""

    def __init__(self, messages: list[str]):
        super().__init__("\n".join(messages))
        self.messages = messages


class DependencyMissing(BakeError):
    """A compiled dependency (embreex, xatlas, OpenEXR) could not be imported."""


class FullBakeNeeded(BakeError):
    """A bake of some receivers into the existing files (Bake Selected / Bake Changed, CLI
    `bake --only` / `--changed`) cannot be done: no earlier bake, the atlas layout or the bake
    settings changed since it (`core.incremental`). Nothing was written; bake all."""
