"""Helpers shared by the tests (on the pytest path through ``pythonpath``)."""

import contextlib
import io
import signal

import numpy as np


def mueller_to_numpy(M):
    """4x4 Dr.Jit/Mitsuba matrix -> float64 array (4, 4, N) for mono entries,
    (4, 4, N, C) for spectral ones; constant entries are broadcast."""
    entries = [[np.array(M[i, j], dtype=np.float64) for j in range(4)] for i in range(4)]
    entries = [[e.T if e.ndim == 2 else np.atleast_1d(e) for e in row] for row in entries]
    shape = np.broadcast_shapes(*[e.shape for row in entries for e in row])
    return np.array([[np.broadcast_to(e, shape) for e in row] for row in entries])


def default_sigint():
    """``preexec_fn`` for children that must see Ctrl-C: SIGINT back to its default action.

    A command started in the background by a non-interactive shell (``make test &``,
    some CI runners) inherits SIGINT ignored, and Python then never raises
    KeyboardInterrupt; a test that sends SIGINT would see the child run to the end.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_cli(*argv):
    """``(exit status, stdout, stderr)`` of ``polarbssrdf ARGV`` run in this process."""
    from polarbssrdf.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()
