"""What the entry points (`experiments/*.py`) share: user errors end the program with one message
naming the key or file, never a traceback.

    with user_errors():
        ...  # the driver's work

A `ConfigError`, a `SequenceError`, a refused run folder and the other input errors whose
message names the config key or the file print `error: <message>` on stderr and exit with
status 2; Ctrl-C prints one line saying what was saved and how to resume (`RunInterrupted`'s
message from the pipeline, or a plain "interrupted") and exits with 130, the shell's status
for SIGINT. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager

from sgdr.anchors.sampling import AnchorInputError
from sgdr.backend import BackendError
from sgdr.checks import ConfigError
from sgdr.data.sequence import SequenceError
from sgdr.physics.model import PhysicsInputError
from sgdr.run_folder import RunFolderError


def input_errors() -> tuple[type[Exception], ...]:
    """The exceptions that report a bad input (their messages name the key or the file)."""

    return (ConfigError, SequenceError, RunFolderError, BackendError, PhysicsInputError, AnchorInputError)


@contextmanager
def user_errors(*extra: type[Exception]):
    """`extra`: further exception types the driver reports as input errors (e.g. FileNotFoundError
    for a driver whose input is a run folder)."""
    try:
        yield
    except KeyboardInterrupt:
        print("interrupted: nothing of the current step is kept; rerun the same command", file=sys.stderr, flush=True)
        sys.exit(130)
    except Exception as exc:
        from sgdr.pipeline.run import RunInterrupted  # imported only now: the backend is set up

        if isinstance(exc, RunInterrupted):
            print(str(exc), file=sys.stderr, flush=True)
            sys.exit(130)
        if isinstance(exc, (*input_errors(), *extra)):
            print(f"error: {exc}", file=sys.stderr, flush=True)
            sys.exit(2)
        raise
