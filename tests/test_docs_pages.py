"""The README is a short front door with a picture, and the documentation site has every page it links to.

The site itself is built by ``make docs`` (mkdocs --strict, which fails on a broken link or API reference); these
checks need no mkdocs and run with the suite.
"""

import os
import re

import pytest

from pcdof.cli import SUBCOMMANDS

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()


def nav_pages() -> list[str]:
    """The .md files mkdocs.yml's nav names (read as text: no YAML library needed)."""
    text = open(os.path.join(ROOT, "mkdocs.yml"), encoding="utf-8").read()
    nav = text.split("\nnav:\n", 1)[1].split("\n\n", 1)[0]
    return re.findall(r":\s*([\w./-]+\.md)\s*$", nav, flags=re.M)


def test_readme_is_short_with_a_picture_in_its_first_screen():
    lines = README.splitlines()
    assert len(lines) <= 300
    pictures = [m for line in lines[:80] for m in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", line)]
    assert pictures, "no picture in the README's first 80 lines"
    for path in pictures:
        full = os.path.join(ROOT, path)
        assert os.path.isfile(full) and 10_000 < os.path.getsize(full) < 400_000, path  # a real picture, modest


def test_readme_links_resolve():
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", README):
        assert os.path.exists(os.path.join(ROOT, target)), target


def test_every_nav_page_exists_and_there_are_enough():
    pages = nav_pages()
    assert len(pages) >= 6
    for page in pages:
        assert os.path.isfile(os.path.join(ROOT, "docs", page)), page
    for needed in ("getting-started.md", "cli.md", "inputs.md", "viewers.md", "batch-and-dask.md", "method.md",
                   "benchmarks.md", "robustness.md", "developing.md", "phone-photos.md", "api.md"):
        assert needed in pages, needed


@pytest.mark.parametrize("command", list(SUBCOMMANDS))
def test_the_cli_page_has_a_section_per_subcommand(command):
    text = open(os.path.join(ROOT, "docs", "cli.md"), encoding="utf-8").read()
    assert re.search(rf"^## {command}$", text, flags=re.M), command


def load_hooks():
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", os.path.join(ROOT, "scripts", "docs_hooks.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_api_page_documents_every_public_name_where_it_is_defined():
    import pcdof

    hooks = load_hooks()
    assert hooks.MARKER in open(os.path.join(ROOT, "docs", "api.md"), encoding="utf-8").read()
    exports = hooks.public_names()
    assert list(exports) == list(pcdof.__all__)  # read from the source, as the package resolves them
    text = hooks.api_markdown(exports)
    for name in pcdof.__all__:
        defined_in = getattr(pcdof, name).__module__ if hasattr(getattr(pcdof, name), "__module__") else None
        block = f"::: pcdof.{exports[name]}.{name}"
        assert re.search(rf"^{re.escape(block)}$", text, flags=re.M), name
        if defined_in is not None and not isinstance(getattr(pcdof, name), dict):
            # the block's module is the one that defines the name, or the package that re-exports it
            assert defined_in.startswith(f"pcdof.{exports[name]}"), (name, defined_in)
    for needed in ("pcdof.lens.ThinLens", "pcdof.pipeline.render", "pcdof.options.RenderOptions", "pcdof.io.load_frame"):
        assert f"::: {needed}\n" in text


def test_the_api_hook_refuses_a_package_without_exports(tmp_path):
    hooks = load_hooks()
    (tmp_path / "init.py").write_text("x = 1\n")
    with pytest.raises(ValueError, match="no _EXPORTS"):
        hooks.public_names(tmp_path / "init.py")
    assert hooks.on_page_markdown("no marker here", None, None, None) == "no marker here"
