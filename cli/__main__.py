"""`python -m hhd_lightmapper.cli FILE.blend COMMAND [options]`: `standalone` under the bpy module,
its exit code the process's. A Ctrl-C or SIGTERM while bpy and numpy load exits 5 at once
(`core.console.exit_on_stop_signal`), not with a broken import: the package's `__init__` and
`codes` import neither, so the handlers are in place before they load."""

import sys

from ..core.console import exit_on_stop_signal
from .codes import COMMAND, EXIT_CANCELLED

exit_on_stop_signal(EXIT_CANCELLED, COMMAND)

from .. import blender_compat  # noqa: E402
from . import standalone  # noqa: E402

blender_compat.exit_process(standalone(sys.argv[1:]))
