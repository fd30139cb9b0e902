"""occloc receiver: frames in, LED IDs, distances and positions out."""

import os as _os
import signal as _signal
import sys as _sys

__version__ = "0.1.0"


def _interrupted_while_loading(signum, frame):
    _sys.stderr.write("occloc: interrupted\n") if _sys.stderr is not None else None
    raise SystemExit(130)


# Started as the `occloc` command (`python -m receiver.cli`, where argv[0] is "-m" while the
# module is found, or the `occloc` script): Ctrl-C while the modules load exits 130 without a
# traceback. receiver.cli.main puts Python's own handler back before any command runs. As a
# library (imported by other code) nothing is changed.
if ((_sys.argv[:1] == ["-m"] or _os.path.basename(_sys.argv[0] if _sys.argv else "") == "occloc")
        and _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler):
    _signal.signal(_signal.SIGINT, _interrupted_while_loading)
