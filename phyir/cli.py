"""``phyir``: one command with subcommands.

Each subcommand is a module with ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``:
the library's own in ``phyir/commands/<name>.py``, others (``insert``, from the viewer package, which
owns GL) registered in the ``phyir.commands`` entry-point group, so the library never names the app.
Command modules import heavy dependencies inside ``run`` so ``phyir --help`` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import importlib.metadata
import importlib.util
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence

# Idle OpenMP threads sleep instead of spinning (set before torch loads; matters on busy small CPUs).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from phyir import __version__
from phyir.errors import InputError, PhyIRError, os_error, shown

# The library's subcommands, in display order; plug-ins (entry points) are placed by PLUGIN_ORDER.
COMMANDS = ("info", "synth", "train", "predict", "eval", "export", "bench")
PLUGIN_GROUP = "phyir.commands"
PLUGIN_ORDER = {"insert": COMMANDS.index("bench")}  # listed before ``bench``


def command_modules() -> dict[str, str]:
    """Subcommand name -> module, the library's and the installed plug-ins', in display order."""
    mods = {name: f"phyir.commands.{name}" for name in COMMANDS}
    order = list(mods)
    for ep in sorted(importlib.metadata.entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
        if ep.name not in mods:
            order.insert(PLUGIN_ORDER.get(ep.name, len(order)), ep.name)
            mods[ep.name] = ep.value
    return {name: mods[name] for name in order}


class Terminated(KeyboardInterrupt):
    """[issue 22, class 4] SIGTERM (or SIGHUP: the terminal closed), raised like Ctrl-C's
    KeyboardInterrupt so the same cleanup (atomic writes removing their temporaries, training's
    checkpoint) runs; ``phyir`` exits 128 + the signal's number (143, 129)."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signum)
        self.signum = int(signum)


# the signals that end a command through Terminated (SIGINT is Python's KeyboardInterrupt)
TERMINATING = (signal.SIGTERM,) + ((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ())


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """While the block runs (in the main thread), SIGTERM and SIGHUP raise :class:`Terminated`; a
    process forked inside it (a DataLoader worker) keeps the default: it just ends.  A SIGHUP that
    was ignored when the command started (``nohup``) stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    owner = os.getpid()

    def handler(signum, _frame):
        if os.getpid() != owner:
            signal.signal(signum, signal.SIG_DFL)
            signal.raise_signal(signum)
        raise Terminated(signum)

    saved = {s: signal.getsignal(s) for s in TERMINATING}
    for s, old in saved.items():
        if old != signal.SIG_IGN:
            signal.signal(s, handler)
    try:
        yield
    finally:
        for s, old in saved.items():
            signal.signal(s, signal.SIG_DFL if old is None else old)


class OneLineParser(argparse.ArgumentParser):
    """[issue 22, class 7] A bad option is one line (``phyir insert: error: argument --fov: ...``),
    not argparse's usage block and then the error; exit 2 as before.  Subparsers inherit it."""

    def error(self, message: str):
        if message.startswith("the following arguments are required"):
            # a mistyped option (--ouput) left a required one (--output) unset: name the typo first
            unknown = self.unknown_options(self._arg_strings)
            if unknown:
                message = f"{self.unrecognized(unknown)}; {message}"
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    # -- mistyped options: the nearest option of the command that was given, and its --help -------
    _arg_strings: tuple[str, ...] = ()

    def parse_known_args(self, args=None, namespace=None):
        self._arg_strings = tuple(sys.argv[1:] if args is None else args)  # a subcommand's: its own words
        return super().parse_known_args(args, namespace)

    def parse_args(self, args=None, namespace=None):
        """argparse's, but an unrecognized option is refused by the subcommand's parser (its name and
        its --help, not ``phyir --help``) with the nearest option it has."""
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            owner = self._subcommand_parser(ns)
            unknown = owner.unknown_options(extras)
            owner.error(owner.unrecognized(unknown) if unknown
                        else f"unrecognized arguments: {' '.join(extras)}")
        return ns

    def _subcommand_parser(self, ns: argparse.Namespace) -> OneLineParser:
        """The parser of the subcommand ``ns`` ran (a plug-in's too), else this one."""
        for action in self._actions:
            if isinstance(action.choices, dict):  # the subcommands: name -> parser
                sub = action.choices.get(getattr(ns, action.dest, None) or "")
                if isinstance(sub, OneLineParser):
                    return sub._subcommand_parser(ns)
        return self

    def unknown_options(self, arg_strings: Sequence[str]) -> list[str]:
        """The words of ``arg_strings`` that look like options this parser does not have (an
        unambiguous prefix of a long option, ``--opt=value`` and ``-oVALUE`` are its own)."""
        known = self._option_string_actions
        out = []
        for arg in arg_strings:
            if arg == "--":
                break
            if not arg.startswith("-") or arg == "-" or _is_number(arg):
                continue
            head = arg.split("=", 1)[0]
            if head in known or (not arg.startswith("--") and arg[:2] in known):
                continue
            if arg.startswith("--") and self.allow_abbrev and any(o.startswith(head) for o in known):
                continue
            out.append(head)
        return out

    def unrecognized(self, unknown: list[str]) -> str:
        """``unrecognized option --ouput (did you mean --output?)``: the first of ``unknown``, the
        option of this parser nearest to it (difflib), if any is near."""
        import difflib

        long = unknown[0].startswith("--")
        options = [o for o in self._option_string_actions if o.startswith("--") == long]
        near = difflib.get_close_matches(unknown[0], options, n=1, cutoff=0.6)
        more = f" (and {', '.join(unknown[1:])})" if len(unknown) > 1 else ""
        hint = f" (did you mean {near[0]}?)" if near else ""
        return f"unrecognized option {unknown[0]}{more}{hint}"

    def _get_value(self, action, arg_string):
        """[issue 22, class 9] A PhyIRError raised by an option's type function is the message
        ("argument --size: expected ..."), not argparse's "invalid _size value"."""
        try:
            return super()._get_value(action, arg_string)
        except argparse.ArgumentError as e:
            cause = e.__context__
            if not isinstance(cause, PhyIRError):
                raise
            named = isinstance(cause, InputError) and cause.path in action.option_strings
            raise argparse.ArgumentError(action, cause.problem if named else str(cause)) from None


def _is_number(word: str) -> bool:
    """``-3``, ``-1e-3``, ``-2,5`` (a value such as ``--yaw -30`` or ``--at -1,2``), not an option."""
    try:
        [float(w) for w in word.split(",")]
    except ValueError:
        return False
    return True


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="phyir",
        description="Physics-based inverse rendering of indoor 360° panoramas (PhyIR).",
    )
    parser.add_argument("--version", action="version", version=f"phyir {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, modname in command_modules().items():
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _requires=getattr(mod, "REQUIRES", ()))
    return parser


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # blocked, or a module set to None in sys.modules
        return False


def check_requirements(command: str, requires: tuple[str, str, tuple[str, ...]] | tuple) -> None:
    """A plug-in's ``REQUIRES = (extra, what, modules)``: refuse in one line when a module is missing."""
    if not requires:
        return
    extra, what, modules = requires
    missing = [m for m in modules if not _installed(m)]
    if missing:
        raise PhyIRError(f"{what} needs the {extra!r} extra, missing {', '.join(missing)}: "
                         f"pip install 'phyir[{extra}]'")


@contextlib.contextmanager
def one_line_warnings(command: str) -> Iterator[None]:
    """[issue 22, class 9] Warnings (the loaders' repairs, ...) as ``phyir <cmd>: warning: <message>``
    on one line, not Python's ``file.py:244: InputWarning: ...`` followed by a line of source."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"phyir {command}: warning: {shown(str(message))}", file=sys.stderr if file is None else file)

    saved = warnings.showwarning
    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = saved


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, or a refused option (its one line is printed)
        return e.code if isinstance(e.code, int) else 2
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        with sigterm_raises(), one_line_warnings(args.command):
            check_requirements(args.command, args._requires)
            return int(args._run(args) or 0)
    except PhyIRError as e:
        print(f"phyir {args.command}: error: {shown(str(e))}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # stdout's reader went away (`phyir info ... | head`): end quietly
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + 13  # as if killed by SIGPIPE, the shell's convention
    except OSError as e:  # the file system's refusals (read-only, full, no permission): one line
        print(f"phyir {args.command}: error: {shown(str(os_error(None, e)))}", file=sys.stderr)
        return 2
    except Terminated as e:
        how = "hung up (SIGHUP)" if e.signum == getattr(signal, "SIGHUP", None) else "terminated"
        print(f"phyir {args.command}: {how}", file=sys.stderr)
        return 128 + e.signum
    except KeyboardInterrupt:
        print(f"phyir {args.command}: interrupted", file=sys.stderr)
        return 130


def console_main() -> None:
    """The ``phyir`` command: :func:`main`, then the exit.  Every object is frozen first so that the
    interpreter's last garbage collection skips the hundred thousand it holds once torch is
    imported: a tenth of a second of a one-panorama ``phyir predict`` went on that sweep.  (Not in
    :func:`main`, which tests and scripts call in-process: frozen objects are never freed.)"""
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    console_main()
