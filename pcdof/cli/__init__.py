"""Command-line interface: a thin shell over the public API.

Each subcommand lives in its own module ``pcdof/cli/<name>.py`` that defines a click command
named ``command``; they are imported only when used, so ``pcdof --help`` stays fast.
"""

from __future__ import annotations

import importlib

import click

#: subcommand name -> (module, one-line help)
SUBCOMMANDS = {
    "demo": ("pcdof.cli.demo", "Render the bundled sample scene and write the results."),
    "render": ("pcdof.cli.render", "Render one RGB-D frame with a shallow depth of field."),
    "register": ("pcdof.cli.register", "Register depth into the colour camera and write it."),
    "cloud": ("pcdof.cli.cloud", "Export the coloured point cloud (colour camera frame) as PLY."),
    "view": ("pcdof.cli.view", "Inspect the focal plane and depth of field in 3D (PyVista)."),
    "batch": ("pcdof.cli.batch", "Render a sequence or dataset of RGB-D frames."),
    "bench": ("pcdof.cli.bench", "Benchmark time against error on the ray-traced ground truth."),
    "synth": ("pcdof.cli.synth", "Generate a synthetic RGB-D scene with ray-traced ground truth."),
}


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return list(SUBCOMMANDS)

    def get_command(self, ctx, name):
        if name not in SUBCOMMANDS:
            return None
        module = importlib.import_module(SUBCOMMANDS[name][0])
        return module.command

    def format_commands(self, ctx, formatter):
        rows = [(name, help_) for name, (_, help_) in SUBCOMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pcdof")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug, with tracebacks).")
@click.pass_context
def main(ctx: click.Context, verbose: int) -> None:
    """pcdof: physically plausible depth of field from one RGB-D frame."""
    from ._common import configure_logging

    ctx.ensure_object(dict)
    ctx.obj["verbose"] = verbose
    configure_logging(verbose)
