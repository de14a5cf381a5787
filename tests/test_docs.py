"""The documentation stays true to the code: every ``nue ...`` line in the bash blocks of README.md, CONTRIBUTING.md
and docs/*.md names a command that exists with options its ``--help`` lists (run in process through
:func:`nue.cli.main`), the README's command tour names every command, every relative link points at a file (and a
heading, for ``#anchor`` links), and results/ holds no scripts."""

from __future__ import annotations

import contextlib
import functools
import io
import re
from pathlib import Path

import pytest

from nue.cli import main

ROOT = Path(__file__).resolve().parents[1]
COMMAND_DOCS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]
"""Files whose bash blocks must hold runnable ``nue`` lines (docs/history/ records past commands as they were)."""
LINK_DOCS = [*COMMAND_DOCS, *sorted((ROOT / "docs" / "history").glob("*.md")), ROOT / "checkpoints" / "README.md",
             ROOT / "benchmarks" / "README.md", ROOT / "scripts" / "README.md",
             *sorted((ROOT / "results").glob("*/README.md"))]
GROUPS = ("scenes", "episodes")
"""Commands with subcommands (``nue scenes generate``)."""


def bash_lines(path: Path) -> list[str]:
    """The command lines of the ```` ```bash ```` blocks of a markdown file: continuations joined, comments cut."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", path.read_text(), flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.split(r"(?:^|\s)#", line, maxsplit=1)[0].strip()
            if line:
                lines.append(line)
    return lines


def nue_argv(line: str) -> list[str] | None:
    """The arguments after ``nue`` (or ``-m nue.cli``) of a command line, or None if it does not run nue."""
    tokens = line.split()
    for i, tok in enumerate(tokens[:-1]):
        if tok == "-m" and tokens[i + 1] == "nue.cli":  # torchrun ... -m nue.cli train ...
            return tokens[i + 2:]
    for i, tok in enumerate(tokens):
        if tok == "nue" or tok.endswith("/nue"):
            return tokens[i + 1:]
        if "=" not in tok:  # only VAR=value prefixes may come before the command
            return None
    return None


def command_of(argv: list[str]) -> tuple[str, ...]:
    return tuple(argv[:2]) if argv and argv[0] in GROUPS else tuple(argv[:1])


def options_of(argv: list[str]) -> set[str]:
    """``--name`` / ``-c`` options of a line, with ``[``, ``]``, ``=value`` and ``|`` alternatives taken apart."""
    out = set()
    for tok in argv:
        for part in tok.strip("[]").split("|"):
            part = part.strip("[]")
            if re.fullmatch(r"--?[a-z][a-z0-9-]*(=.*)?", part):
                out.add(part.split("=")[0])
    return out


def documented() -> dict[tuple[str, ...], dict[str, set[str]]]:
    """command -> {doc file: options used with it there}."""
    found: dict[tuple[str, ...], dict[str, set[str]]] = {}
    for path in COMMAND_DOCS:
        for line in bash_lines(path):
            argv = nue_argv(line)
            if argv:
                opts = found.setdefault(command_of(argv), {}).setdefault(str(path.relative_to(ROOT)), set())
                opts |= options_of(argv[len(command_of(argv)):])
    return found


@functools.cache
def help_text(command: tuple[str, ...]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as done:
        main([*command, "--help"])
    assert done.value.code in (0, None), f"nue {' '.join(command)} --help exited with {done.value.code}"
    return out.getvalue()


DOCUMENTED = documented()


def test_the_docs_hold_command_lines():
    readme = {c for c, where in DOCUMENTED.items() if "README.md" in where}
    assert {("demo",), ("eval",), ("reproduce",), ("view",), ("scenes", "generate")} <= readme


@pytest.mark.parametrize("command", sorted(DOCUMENTED), ids=" ".join)
def test_documented_commands_exist_with_their_options(command, monkeypatch):
    monkeypatch.setenv("COLUMNS", "250")
    text = help_text(command)
    for doc, options in DOCUMENTED[command].items():
        missing = sorted(o for o in options if not re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", text))
        assert not missing, f"{doc}: nue {' '.join(command)} has no option {', '.join(missing)}"


def test_the_readme_tours_every_command(monkeypatch):
    monkeypatch.setenv("COLUMNS", "250")
    readme = {c for c, where in DOCUMENTED.items() if "README.md" in where}
    listed = set()
    for top in [()] + [(g,) for g in GROUPS]:
        text = help_text(top)
        names = re.findall(r"^[│|\s]*([a-z][a-z-]*)\s{2,}\S", text.split("Commands", 1)[-1], flags=re.M)
        listed |= {(*top, n) for n in names if n not in GROUPS}
    if not listed:
        pytest.skip("the command list of nue --help is not in a form this test reads")
    assert listed - readme == set(), "README.md's command tour leaves out these commands"


def _slug(heading: str) -> str:
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize("path", LINK_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_at_files(path):
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        assert dest.exists(), f"{path.relative_to(ROOT)}: link to {target}: no such file"
        if anchor and dest.suffix == ".md":
            headings = {_slug(h) for h in re.findall(r"^#+ (.+)$", dest.read_text(), flags=re.M)}
            assert anchor in headings, f"{path.relative_to(ROOT)}: link to {target}: no such heading"


def test_results_hold_data_and_reports_only():
    scripts = sorted(str(p.relative_to(ROOT)) for ext in ("py", "sh") for p in (ROOT / "results").rglob(f"*.{ext}"))
    assert not scripts, f"scripts under results/ (they belong in scripts/): {scripts}"
