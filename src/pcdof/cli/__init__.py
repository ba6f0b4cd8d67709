"""Command-line interface: a thin shell over the public API.

Each subcommand lives in its own module ``pcdof/cli/<name>.py`` that defines a click command
named ``command``; they are imported only when used, so ``pcdof --help`` stays fast.

Conventions shared by every subcommand, implemented once here:

* ``-v/-vv/-q`` are accepted before or after the subcommand (``pcdof -v render ...`` and
  ``pcdof render -v ...`` are the same); ``-q`` silences the line a command prints about what it
  decided (:mod:`pcdof.cli._report`), never an error or a warning.
* A usage error (unknown option or command, bad or missing value, invalid choice) is one line on
  stderr, ``pcdof: error: <message> (see 'pcdof <command> -h')``, and exit status 2; pcdof's own
  errors use the same prefix and the exit codes of :data:`pcdof.errors.EXIT_CODES`.
"""

from __future__ import annotations

import difflib
import gc
import importlib
import logging

import click

#: subcommand name -> (module, one-line help)
SUBCOMMANDS = {
    "demo": ("pcdof.cli.demo", "Render the bundled frames and show the effect side by side."),
    "render": ("pcdof.cli.render", "Render one RGB-D frame with a shallow depth of field."),
    "register": ("pcdof.cli.register", "Register depth into the colour camera and write it."),
    "cloud": ("pcdof.cli.cloud", "Export the coloured point cloud (colour camera frame) as PLY."),
    "view": ("pcdof.cli.view", "Inspect the focal plane and depth of field in 3D (PyVista)."),
    "batch": ("pcdof.cli.batch", "Render a sequence or dataset of RGB-D frames."),
    "bench": ("pcdof.cli.bench", "Benchmark time against error on the ray-traced ground truth."),
    "synth": ("pcdof.cli.synth", "Generate a synthetic RGB-D scene with ray-traced ground truth."),
    "info": ("pcdof.cli.info", "Describe a recording (.mkv / .bag) or phone depth photo: streams, depth, calibration."),
    "export": ("pcdof.cli.export", "Write a recording's frames as colour/depth PNGs and calib.json."),
    "warmup": ("pcdof.cli.warmup", "Compile every stage's kernels now (once after install), with progress."),
}

VERBOSE_HELP = "More log output (-vv for debug, with tracebacks); also after the subcommand."
QUIET_HELP = "Do not print what the command decided (errors and warnings still show); also after the subcommand."


class OneLineUsageError(click.UsageError):
    """A click usage error shown as pcdof shows every error: one line on stderr, exit status 2."""

    def __init__(self, error: click.UsageError):
        super().__init__(" ".join(error.format_message().split()), error.ctx)

    def show(self, file=None) -> None:
        hint = ""
        if self.ctx is not None:
            hint = f" (see '{self.ctx.command_path} -h')"
        click.echo(f"pcdof: error: {self.message}{hint}", file=file, err=file is None)


def _one_line(error: click.UsageError) -> click.UsageError:
    # a bare `pcdof` shows the help (click's NoArgsIsHelpError), which is not a one-line message
    if isinstance(error, (OneLineUsageError, click.exceptions.NoArgsIsHelpError)):
        return error
    return OneLineUsageError(error)


def _settings(ctx: click.Context) -> dict:
    root = ctx.find_root()
    if not isinstance(root.obj, dict):
        root.obj = {}
    root.obj.setdefault("verbose", 0)
    root.obj.setdefault("quiet", False)
    return root.obj


def _apply_logging(settings: dict) -> None:
    from ._common import configure_logging

    configure_logging(settings["verbose"])  # installs pcdof's handler and warning format (once)
    verbose = settings["verbose"]
    logging.getLogger().setLevel(logging.WARNING if verbose == 0 else logging.INFO if verbose == 1
                                 else logging.DEBUG)


def _add_verbose(ctx: click.Context, param, value: int) -> int:
    settings = _settings(ctx)
    settings["verbose"] += value or 0
    _apply_logging(settings)
    return value


def _add_quiet(ctx: click.Context, param, value: bool) -> bool:
    _settings(ctx)["quiet"] |= bool(value)
    return value


def verbosity_options() -> list[click.Option]:
    """``-v/--verbose`` and ``-q/--quiet``, adding to what the group's own flags set."""
    return [click.Option(["-v", "--verbose"], count=True, expose_value=False, callback=_add_verbose,
                         help=VERBOSE_HELP),
            click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, callback=_add_quiet,
                         help=QUIET_HELP)]


def _with_verbosity(command: click.Command) -> click.Command:
    """*command* with the verbosity options (added once; a command that defines its own -v/-q keeps them)."""
    taken = {opt for p in command.params for opt in getattr(p, "opts", [])}
    if not getattr(command, "_pcdof_verbosity", False) and not taken & {"-v", "--verbose", "-q", "--quiet"}:
        command.params.extend(verbosity_options())
        command._pcdof_verbosity = True
    return command


#: True when :func:`console_main` runs this process (the ``pcdof`` console script)
_own_process = False


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return list(SUBCOMMANDS)

    def get_command(self, ctx, name):
        if name not in SUBCOMMANDS:
            return None
        module = importlib.import_module(SUBCOMMANDS[name][0])
        if _own_process:
            gc.freeze()  # see console_main
        return _with_verbosity(module.command)

    def resolve_command(self, ctx, args):
        name = args[0] if args else ""
        if name and name not in SUBCOMMANDS and not name.startswith("-"):
            close = difflib.get_close_matches(name, list(SUBCOMMANDS), n=1, cutoff=0.6)
            hint = f" Did you mean '{close[0]}'?" if close else ""
            raise click.UsageError(f"No such command '{name}'.{hint}", ctx)
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx, formatter):
        rows = [(name, help_) for name, (_, help_) in SUBCOMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    # the group's own arguments are parsed in make_context; a subcommand's, and its body, run in invoke
    def make_context(self, *args, **kwargs):
        try:
            return super().make_context(*args, **kwargs)
        except click.UsageError as err:
            raise _one_line(err) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as err:
            raise _one_line(err) from None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pcdof")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug, with tracebacks).")
@click.option("-q", "--quiet", is_flag=True, help="Do not print what the command decided.")
@click.pass_context
def main(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """pcdof: physically plausible depth of field from one RGB-D frame."""
    settings = _settings(ctx)
    settings["verbose"] += verbose
    settings["quiet"] |= quiet
    _apply_logging(settings)


def console_main() -> None:
    """The ``pcdof`` console script: :func:`main` in a process of its own.

    Ctrl-C is pcdof's from the start (:mod:`pcdof.interrupts`: the console script,
    the top-level module ``pcdof_console``, installs the handler before this module is imported): one ``pcdof: interrupted`` line and exit status 130 at any moment,
    and once a command has ended, Ctrl-C is ignored and the exit is given :data:`pcdof.interrupts.EXIT_GRACE_S`
    seconds (:func:`pcdof.interrupts.ending`): the exit status is the command's, and no thread left running
    can hold the process.

    What a command imports lives until the process ends, so the garbage collector is told to leave it out of
    its passes (``gc.freeze``) once the command's module is imported, and again as the process ends: the
    collector's full passes over numba's and the modules' objects otherwise took about 0.25 s of a one-shot
    ``pcdof render`` (most of it at exit). Nothing else changes: files are written and closed by then, and
    exit handlers run as before. In-process callers (tests, notebooks) use :func:`main` and keep the collector
    as it was.
    """
    global _own_process
    from .. import interrupts

    _own_process = True
    from ..runtime.process import tune_process

    tune_process()  # before numba or OpenMP loads: they read their settings once
    try:
        main()
    except SystemExit as done:
        if interrupts.installed():  # the command is over: its exit status stands, whatever comes now
            interrupts.ending(done.code if isinstance(done.code, int) else 1 if done.code else 0)
        raise
    except KeyboardInterrupt:  # outside a command's body (click's own "Aborted!" would say exit 1)
        interrupts.exit_now()
    finally:
        gc.freeze()
