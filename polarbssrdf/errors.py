"""Exceptions shared across the package, the user-facing text of Mitsuba's errors, and how a
command turns the errors a user can fix into one line (:func:`run_command`)."""

from __future__ import annotations

import contextvars
import re
import sys

__all__ = ["CommandError", "EXIT_INTERRUPTED", "EXIT_USER_ERROR", "USER_ERRORS",
           "caused_by_interrupt", "is_plugin_error", "option", "plugin_error_message",
           "run_command"]

_TRACEBACK_HEADER = "Traceback (most recent call last):"

_SOURCE_TAG = re.compile(r"\[[\w.]+:\d+\]\s*")
"""Mitsuba's ``[parser.cpp:1718] `` source-location tags, which mean nothing to a user."""

_PLAIN_EXCEPTION_TYPES = ("ValueError",)
"""Exception types whose name adds nothing: plugins raise them for invalid parameters."""


EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C: 128 + SIGINT, as shells report it."""


class CommandError(RuntimeError):
    """An error the user can fix; the command line prints it without a traceback."""


def is_plugin_error(error: BaseException) -> bool:
    """Whether ``error`` is Mitsuba's wrapper around an exception raised in a Python plugin.

    Mitsuba turns an exception raised in a Python plugin's ``__init__`` into a
    ``RuntimeError`` whose text is its own context ("At FILE (line L, col C):
    failed to instantiate bsdf plugin of type ...") followed by the whole
    Python traceback.
    """
    return isinstance(error, RuntimeError) and _TRACEBACK_HEADER in str(error)


def is_interrupted_plugin(error: BaseException) -> bool:
    """Whether ``error`` is Mitsuba's wrapper around a Ctrl-C inside a Python plugin.

    A ``KeyboardInterrupt`` raised while Mitsuba constructs a Python plugin
    reaches the caller as a plugin error (:func:`is_plugin_error`) whose
    embedded traceback ends in ``KeyboardInterrupt``; the exception itself is gone.
    """
    if not is_plugin_error(error):
        return False
    traceback_text = str(error).rpartition(_TRACEBACK_HEADER)[2]
    lines = _exception_lines(traceback_text)
    return bool(lines) and lines[-1].startswith("KeyboardInterrupt")


def _exception_lines(traceback_text: str) -> list[str]:
    """The final ``Type: message`` lines of a formatted traceback (its frames are indented)."""
    lines = traceback_text.splitlines()
    first = next((i for i, line in enumerate(lines) if line and not line[0].isspace()),
                 len(lines))
    return [line for line in lines[first:] if line.strip()]


def plugin_error_message(error: BaseException) -> str:
    """One line for the user from a Mitsuba error, without an embedded Python traceback.

    Parameters
    ----------
    error:
        Typically the ``RuntimeError`` of :func:`mitsuba.load_file` or
        :func:`mitsuba.load_dict`. If a Python plugin raised in its
        constructor, Mitsuba's text carries the traceback; only Mitsuba's
        context (file, line, plugin) and the plugin's own message are kept.

    Returns
    -------
    str
        E.g. ``At scene.xml (line 53, col 10): failed to instantiate bsdf
        plugin of type "pbssrdf": pbssrdf: parameter 'rho_sss' = 1.7 is
        outside its valid range [0, 1]``. Errors without a traceback come
        back as their text, minus Mitsuba's source-file tags.
    """
    text = str(error).strip()
    context, header, traceback_text = text.rpartition(_TRACEBACK_HEADER)
    if not header:
        return _SOURCE_TAG.sub("", text)
    message = " ".join(_exception_lines(traceback_text)) or "error in a Python plugin"
    kind, sep, rest = message.partition(": ")
    if sep and kind in _PLAIN_EXCEPTION_TYPES:
        message = rest
    # With nested plugins the context may itself hold an earlier traceback's header.
    context = _SOURCE_TAG.sub("", context.split(_TRACEBACK_HEADER)[0]).strip().rstrip(":")
    return f"{context}: {message}" if context else message


def caused_by_interrupt(error: BaseException) -> bool:
    """Whether ``error`` is Ctrl-C, or an error raised because of it.

    Ctrl-C inside a C++ extension can surface as another exception whose cause
    is the ``KeyboardInterrupt``: e.g. during :func:`mitsuba.set_variant`,
    which imports modules, Python reports ``SystemError: <built-in function
    __import__> returned a result with an exception set``; inside a Python
    plugin's constructor Mitsuba reports it as a plugin error whose traceback
    ends in ``KeyboardInterrupt`` (:func:`polarbssrdf.errors.is_interrupted_plugin`).
    """
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt) or is_interrupted_plugin(error):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


_ON_COMMAND_LINE = contextvars.ContextVar("polarbssrdf_on_command_line", default=False)
"""True while :func:`run_command` runs a command: messages then name command-line options."""


def option(name: str, value=None) -> str:
    """How a message names a setting the user passed: the command line's option while a
    command runs (:func:`run_command`), else the Python parameter.

    ``option("stages")`` is ``--stages`` or ``stages``; ``option("stages", "static,bio")``
    is ``--stages static,bio`` or ``stages='static,bio'``; ``option("resume", True)`` is
    ``--resume`` or ``resume=True`` (a switch).
    """
    if _ON_COMMAND_LINE.get():
        flag = "--" + name.replace("_", "-")
        return flag if value is None or value is True else f"{flag} {value}"
    return name if value is None else f"{name}={value!r}"


USER_ERRORS = (CommandError, FileNotFoundError, FileExistsError, ValueError)
"""Exceptions whose message is for the user: printed on one line, exit status 2."""


def run_command(args) -> int:
    """Run the parsed command; errors a user can fix become one line on stderr and status 2.

    While it runs, messages name command-line options (:func:`option`).
    """
    token = _ON_COMMAND_LINE.set(True)
    try:
        return int(args.run(args) or 0)
    except Exception as error:
        if caused_by_interrupt(error):  # e.g. a CommandError wrapping a failed import
            raise
        if isinstance(error, USER_ERRORS):
            message = str(error)
        elif is_plugin_error(error):
            # A Python plugin rejected its parameters while Mitsuba built a scene: the
            # plugin's message is for the user, the traceback Mitsuba embeds is not.
            message = plugin_error_message(error)
        else:
            raise
        print(f"polarbssrdf {args.command}: error: {message}", file=sys.stderr)
        return EXIT_USER_ERROR
    finally:
        _ON_COMMAND_LINE.reset(token)
