"""The ``lfring`` command-line app: one small module per command, each a thin shell."""

from __future__ import annotations

import importlib
import logging
import os
import re
import sys
import warnings

import click

from lfring import __version__
from lfring.cli.words import CliFormatter, cli_words
from lfring.core.signals import deliver_lost_stops, interrupt_behind, raise_stop, redelivered_stops, stop_record
from lfring.errors import LfringError

# command name -> module in lfring.cli defining a click command called ``command``.
COMMANDS = {
    "batch": "batch",
    "calibrate": "calibrate",
    "check": "check",
    "depth": "depth",
    "design": "design",
    "grid-calib": "grid_calib",
    "inspect": "inspect",
    "raytrace": "raytrace",
    "refocus": "refocus",
    "split": "split",
    "synth": "synth",
    "view": "view",
}


class _LfringGroup(click.Group):
    """Loads command modules lazily and turns lfring errors into one line on stderr."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        module = COMMANDS.get(name)
        if module is None:
            return None
        return importlib.import_module(f"lfring.cli.{module}").command

    def resolve_command(self, ctx, args):
        name, cmd, rest = super().resolve_command(ctx, args)
        if cmd is not None:
            twice = repeated_option(cmd, rest)
            if twice:
                raise click.UsageError(f"{twice} (lfring {name} --help says which options repeat)")
        return name, cmd, rest

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (LfringError, OSError) as exc:
            stop = interrupt_behind(exc)  # a Ctrl-C that a library turned into its own error
            if stop is not None:
                raise stop from None
            if isinstance(exc, LfringError):
                raise CliError(cli_words(str(exc))) from None
            if isinstance(exc, BrokenPipeError) and exc.filename is None and _stdout_gone():
                raise ReaderGone() from None
            where = f": {exc.filename}" if exc.filename else ""  # any file-system failure: one line naming the path
            raise CliError(f"{exc.strerror or exc}{where}") from None


class ReaderGone(click.ClickException):
    """What the command printed had no reader left (``lfring check frame.png | head``): nothing
    more is said, and the exit code is a shell's for SIGPIPE, as for any command in a pipe."""

    exit_code = 141  # 128 + SIGPIPE, as a shell says

    def __init__(self):
        super().__init__("")

    def show(self, file=None) -> None:
        """Say nothing; standard output goes to the null device, where the interpreter's last
        flush can go."""
        try:  # the interpreter's own flush at exit would fail on the closed pipe and say so
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass


def _stdout_gone() -> bool:
    """Whether standard output is a pipe whose reading end is closed."""
    try:
        import select

        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & select.POLLERR for _, ev in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll (Windows), no file descriptor
        return False


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that it stops as for Ctrl-C: workers ended,
    temporary files removed, nothing partial left (a KeyboardInterrupt, which the library lets
    through)."""


def _terminate(signum, frame):
    raise_stop(Terminated)


def _interrupt(signum, frame):
    raise_stop(KeyboardInterrupt)


def _stopping() -> None:
    """The script is being stopped: a file that the stop drops unclosed (it came between the
    file's opening and its ``with``, in our code or the standard library's) is the stop's, not a
    leak to report; under -W error its ResourceWarning would print a traceback after our line."""
    warnings.filterwarnings("ignore", category=ResourceWarning)


def _terminate_script(signum, frame):
    _stopping()
    raise_stop(Terminated)


def _interrupt_script(signum, frame):
    _stopping()
    raise_stop(KeyboardInterrupt)


#: Exit codes of a command stopped by Ctrl-C and by SIGTERM (128 + the signal's number, as a shell says).
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


class CliError(click.ClickException):
    """A bad input or a failed step: one line on stderr, exit code 2."""

    exit_code = 2

    def show(self, file=None):
        """Print the error as one line, ``lfring: error: MESSAGE``, on stderr (no usage text).

        Parameters
        ----------
        file : file object, optional
            Ignored (click's signature); the line always goes to stderr.
        """
        click.echo(f"lfring: error: {self.format_message()}", err=True)


@click.group(cls=_LfringGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="lfring")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
@click.option("-q", "--quiet", is_flag=True, help="Log only warnings and errors (results, such as the paths written and a batch's summary, still go to stdout).")
def cli(verbose: int, quiet: bool) -> None:
    """lfring: light fields from a four mini-lens ring camera.

    All lengths are in metres unless an option says otherwise.
    """
    # Third-party loggers stay at WARNING; lfring's own at INFO (DEBUG with -vv).
    logging.basicConfig(level=logging.WARNING, format="lfring: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    for handler in logging.getLogger().handlers:  # library messages name API parameters: say the options instead
        handler.setFormatter(CliFormatter("lfring: %(levelname)s: %(message)s"))
    level = logging.WARNING if quiet else (logging.INFO if verbose < 2 else logging.DEBUG)
    logging.getLogger("lfring").setLevel(level)
    # Library warnings (a depth outside the calibrated range, say) become one log line each, in
    # the command line's words (its options for the API's parameters).
    warn_log = logging.getLogger("lfring.warnings")
    warnings.showwarning = lambda message, category, *args, **kwargs: warn_log.warning("%s", cli_words(str(message)))


def repeated_option(command: click.Command, args: list[str]) -> str:
    """Why ``args`` give one of ``command``'s single-valued options more than once ('' where
    none is): click would keep the last value without a word, and a user who wrote
    ``--refocus 0.5 --refocus 0.7`` meant both. Repeatable options and flags may repeat.

    >>> repeated_option(cli.get_command(None, "refocus"), ["a.png", "--depth", "0.5", "--depth=0.7"])
    '--depth is given twice (0.5 and 0.7): give it once'
    """
    single = {opt: p for p in command.params if isinstance(p, click.Option) and not (p.multiple or p.count or p.is_flag)
              for opt in p.opts}
    seen: dict[str, str] = {}
    i = 0
    while i < len(args) and args[i] != "--":
        opt, eq, value = args[i].partition("=") if args[i].startswith("--") else (args[i], "", "")
        param = single.get(opt)
        if param is not None:
            if not eq:
                value = args[i + 1] if i + 1 < len(args) else ""
                i += 1
            if param.name in seen:
                return f"{opt} is given twice ({seen[param.name]} and {value}): give it once"
            seen[param.name] = value
        i += 1
    return ""


_VERBOSITY = {"-q", "--quiet", "-v", "-vv", "-vvv", "--verbose"}


def hoist_verbosity(args: list[str]) -> list[str]:
    """Move -q/-v given after the subcommand in front of it, where the group reads them
    (``lfring refocus x.png --depth 0.5 -q`` is ``lfring -q refocus x.png --depth 0.5``).
    Tokens after ``--`` stay.

    >>> hoist_verbosity(["refocus", "a.png", "-q", "--depth", "0.5"])
    ['-q', 'refocus', 'a.png', '--depth', '0.5']
    """
    args = list(args)
    cmd = next((i for i, a in enumerate(args) if a in COMMANDS), None)
    if cmd is None:
        return args
    end = args.index("--") if "--" in args[cmd:] else len(args)
    moved = [a for a in args[cmd + 1:end] if a in _VERBOSITY]
    rest = [a for a in args[cmd + 1:end] if a not in _VERBOSITY]
    return [*args[:cmd], *moved, args[cmd], *rest, *args[end:]]


def main(argv=None) -> int:
    """Entry point of the ``lfring`` script; returns the exit code (130 after Ctrl-C, 143
    after SIGTERM, each with one line on stderr and no traceback: run as the script, a file that
    the stop drops unclosed is not reported, :func:`_stopping`)."""
    import signal
    import threading

    args = hoist_verbosity(sys.argv[1:] if argv is None else argv)
    if argv is None:
        # Ctrl-C inside an import can drop the file the interpreter's loader was reading
        # unclosed: its ResourceWarning (an error under -W error) is the interpreter's, not the
        # command's, and would come after our one line. Only a script run sets this filter.
        warnings.filterwarnings("ignore", category=ResourceWarning, module=r"importlib\._bootstrap")
    ours = threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    # Ours to replace: Python's default, not where Ctrl-C is ignored or the caller's own.
    ours_int = ours and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    try:
        # Installed inside the try: the finally puts the caller's back whenever a signal comes.
        if ours:
            signal.signal(signal.SIGTERM, _terminate if argv is not None else _terminate_script)
        if ours_int:
            signal.signal(signal.SIGINT, _interrupt if argv is not None else _interrupt_script)
        # A Ctrl-C in a weakref callback of an import still stops the command; the stops that come
        # during it are its own (a command run inside another's has handlers that are not its own).
        with redelivered_stops() if ours else stop_record():
            return _run(args)
    finally:
        # A KeyboardInterrupt that escaped code run from a string (the methods that dataclasses
        # build with exec, when Ctrl-C comes during an import) leaves CPython's "unhandled
        # KeyboardInterrupt" mark set though _run handled it; run as `python -m lfring`, the
        # interpreter then kills itself with SIGINT at exit instead of returning our code.
        # Running any code from a string clears the mark.
        eval("None")
        if ours and argv is None:
            # The command is over and the script exits with its code: a signal now would only cut
            # the interpreter's exit short (killed by it, or a traceback from a KeyboardInterrupt).
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        elif ours:  # called from Python: SIGTERM and SIGINT are the caller's again
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            if ours_int:
                signal.signal(signal.SIGINT, signal.default_int_handler)


_NUMBER = re.compile(r"-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _run(args: list[str]) -> int:
    try:
        rv = cli.main(args=args, prog_name="lfring", standalone_mode=False)
        deliver_lost_stops()  # a Ctrl-C that came where it could not stop the command
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except (click.Abort, KeyboardInterrupt) as exc:
        return _stopped(interrupt_behind(exc))
    except click.NoSuchOption as exc:
        if _NUMBER.fullmatch(exc.option_name or ""):  # a negative value read as an option's name
            exc.message = (f"{exc.option_name} is not an option: was it meant as a value? Depths and distances are "
                           "metres in front of the lens (> 0)")
        exc.show()
        return exc.exit_code
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except Exception as exc:
        stop = interrupt_behind(exc)  # Python 3.10 and 3.11: Ctrl-C inside an import's class creation
        if stop is None:
            raise
        return _stopped(stop)
    # Without standalone mode click returns ctx.exit(code)'s code instead of raising.
    return rv if isinstance(rv, int) else 0


def _stopped(stop) -> int:
    """Say in one line that the command was stopped (by SIGTERM or Ctrl-C), and its exit code."""
    if isinstance(stop, Terminated):
        click.echo("lfring: terminated", err=True)
        return EXIT_TERMINATED
    click.echo("lfring: aborted", err=True)
    return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
