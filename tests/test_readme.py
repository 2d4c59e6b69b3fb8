"""README.md as a newcomer reads and runs it: short enough, every command in its code blocks run as
written (in order, in an empty folder, so the walkthrough builds on itself), every command and flag it
names in prose or tables a real one, and every relative link in it and in docs/ pointing somewhere."""

import ast
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"

#: The README a newcomer reads in ten minutes (issue 30): 15 KB at most.
MAX_README_BYTES = 15 * 1024

#: How the README calls the console script: the set-up's virtual environment, seen from the repository root.
SCRIPT = ".venv/bin/spare-twin"

#: The first code block: the main job and the test suite, each after the set-up.
SETUP = "bash scripts/setup.sh && "
FIRST_BLOCK = [f"{SETUP}{SCRIPT} demo", f"{SETUP}.venv/bin/python -m pytest -q"]

#: Shell syntax a README command line must not use: the test runs it as one argument list, without a shell.
SHELL_SYNTAX = ("&&", "||", "|", ";", ">", "<", "$(", "`")

#: A markdown link or image's target: [text](target) or ![alt](target).
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")

#: A long option as it is written in the text.
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def fenced_blocks(text: str) -> list[list[str]]:
    """The lines of each fenced code block, in order."""
    blocks, current = [], None
    for line in text.splitlines():
        if line.startswith("```"):
            if current is None:
                current = []
            else:
                blocks.append(current)
                current = None
        elif current is not None:
            current.append(line)
    assert current is None, "README.md: a code block is not closed"
    return blocks


def prose(text: str) -> str:
    """The text outside fenced code blocks (a '#' line in a code block is no heading)."""
    kept, inside = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            inside = not inside
        elif not inside:
            kept.append(line)
    return "\n".join(kept)


def walkthrough(blocks: list[list[str]]) -> list[list[str]]:
    """Every `spare-twin` command of the code blocks after the first, as an argument list after the
    script: `$S ARGS` (after `S=.venv/bin/spare-twin`), `.venv/bin/spare-twin ARGS` or `spare-twin ARGS`."""
    commands, script_var = [], None
    for block in blocks[1:]:
        for line in block:
            words = shlex.split(line, comments=True)
            if not words:
                continue
            if words[0].startswith("S="):
                assert words == [f"S={SCRIPT}"], line
                script_var = SCRIPT
                continue
            head = SCRIPT if words[0] == "$S" and script_var else words[0]
            if head not in (SCRIPT, "spare-twin"):
                assert "spare-twin" not in line, f"README.md: a command line the test cannot run: {line}"
                continue
            assert not any(s in w for w in words for s in SHELL_SYNTAX), f"README.md: shell syntax in {line}"
            commands.append(words[1:])
    return commands


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", prose(path.read_text()), flags=re.M)}


def test_readme_is_short():
    size = len(README.read_bytes())
    assert size <= MAX_README_BYTES, f"README.md is {size} bytes, more than {MAX_README_BYTES}"


def test_first_block_is_the_demo_and_the_test_suite():
    first = fenced_blocks(README.read_text())[0]
    assert first == FIRST_BLOCK, first
    # CI runs exactly the README's test command
    ci = [ln for ln in (REPO / ".ci" / "run").read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert ci[-1] == FIRST_BLOCK[1], ci
    # The demo runs in test_demo.py, as the README gives it (no arguments), so it is not run here again.
    tree = ast.parse((REPO / "tests" / "test_demo.py").read_text())
    demo_argv = next(
        ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "DEMO_ARGV" for t in node.targets)
    )
    assert FIRST_BLOCK[0] == f"{SETUP}{SCRIPT} " + " ".join(demo_argv)


def test_every_relative_link_resolves():
    pages = [README, *sorted((REPO / "docs").glob("*.md")), REPO / "CHANGELOG.md"]
    broken = []
    for page in pages:
        for target in LINK.findall(prose(page.read_text())):
            if re.match(r"[a-z]+:", target):  # https:, mailto: ...
                continue
            path_part, _, anchor = target.partition("#")
            dest = (page.parent / path_part).resolve() if path_part else page
            if not dest.exists():
                broken.append(f"{page.relative_to(REPO)}: {target}")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                broken.append(f"{page.relative_to(REPO)}: {target} (no such heading)")
    assert not broken, broken


def command_parsers(span: str) -> list:
    """The subcommand parsers a `spare-twin SUB ...` span names (`bench {a,b}`: both)."""
    from spare_twin.cli import build_parser

    parser, words = build_parser(), span.split()[1:]
    while words and parser._subparsers is not None:
        choices = parser._subparsers._group_actions[0].choices
        if words[0].startswith("{"):
            names = words[0].strip("{}").split(",")
            assert all(name in choices for name in names), f"no such command: {span}"
            return [choices[name] for name in names]
        if words[0] not in choices:
            break
        parser, words = choices[words[0]], words[1:]
    assert parser.prog != "spare-twin", f"no such command: {span}"
    return [parser]


def unknown_flags(text: str, parsers: list) -> list[str]:
    known = {opt for parser in parsers for action in parser._actions for opt in action.option_strings}
    return [flag for flag in FLAG.findall(text) if flag not in known]


def table_rows(page: Path) -> list[tuple[list, str]]:
    """Each command table row: the parsers its first cell names, and the whole row."""
    rows = []
    for line in prose(page.read_text()).splitlines():
        if not line.startswith("| `spare-twin "):
            continue
        first_cell = line.replace("\\|", "/").split("|")[1]
        spans = [s for s in re.findall(r"`([^`]+)`", first_cell) if not s.startswith("--")]
        top = spans[0].split()[1]  # `capture calibrate REC` beside `spare-twin capture board ...`
        parsers = [
            p
            for s in spans
            for p in command_parsers(s if s.startswith("spare-twin ") else f"spare-twin {s}")
            if s.startswith(("spare-twin ", top))
        ]
        rows.append((parsers, line))
    return rows


def test_commands_named_in_the_text_exist():
    """Every `spare-twin SUB ...` in the README's prose names a real subcommand, and each --flag in it
    is one that subcommand takes (placeholders such as OBJ or N are not checked)."""
    spans = re.findall(r"`(spare-twin [^`]+)`", prose(README.read_text()))
    assert len(spans) >= 10, spans
    for span in spans:
        unknown = unknown_flags(span, command_parsers(span))
        assert not unknown, f"README.md: {span}: no such flags {unknown}"


def test_command_tables_are_real_and_complete():
    """The command tables of the README and docs/commands.md: every flag of a row is one its command
    takes, and docs/commands.md has a row for every command there is."""
    from spare_twin.cli import build_parser

    named = set()
    for page in (README, REPO / "docs" / "commands.md"):
        rows = table_rows(page)
        assert len(rows) >= 12, (page, len(rows))
        for parsers, row in rows:
            unknown = unknown_flags(row, parsers)
            assert not unknown, f"{page.name}: {row[:80]}: no such flags {unknown}"
            if page.name == "commands.md":
                named |= {parser.prog for parser in parsers}
    every = set()
    for name, sub in build_parser()._subparsers._group_actions[0].choices.items():
        every.add(sub.prog)
        if name != "bench" and sub._subparsers is not None:  # capture and noise: each subcommand a row
            every |= {leaf.prog for leaf in sub._subparsers._group_actions[0].choices.values()}
    named |= {prog.rsplit(" ", 1)[0] for prog in named}  # `capture import` names `capture` too
    missing = every - named
    assert not missing, f"docs/commands.md has no row for {sorted(missing)}"


def test_every_readme_command_runs(tmp_path):
    """The walkthrough, command by command, as the README gives it: each must succeed, a --json one must
    print one JSON object, and predict must count the links of the object the walkthrough built."""
    commands = walkthrough(fenced_blocks(README.read_text()))
    assert len(commands) >= 5, commands
    exe = str(Path(sys.executable).parent / "spare-twin")
    for argv in commands:
        res = subprocess.run([exe, *argv], cwd=tmp_path, capture_output=True, text=True, timeout=240)
        assert res.returncode == 0, (argv, res.stderr[-2000:])
        if "--json" in argv:
            answer = json.loads(res.stdout)
            if argv[0] == "predict":
                objects = [json.loads(p.read_text()) for p in tmp_path.glob("*/object.json")]
                assert len(objects) == 1 and answer["n_links"] == objects[0]["n_links"], (argv, answer)


def test_architecture_page_names_every_package():
    """docs/architecture.md's tree (linked from the README) names every package and module of the library."""
    tree = (REPO / "docs" / "architecture.md").read_text()
    library = REPO / "spare_twin"
    names = [p.name + "/" for p in library.iterdir() if (p / "__init__.py").is_file()]
    names += [p.name for p in library.glob("*.py") if p.name not in ("__init__.py", "__main__.py")]
    missing = [name for name in sorted(names) if not re.search(rf"(^|[\s,]){re.escape(name)}", tree, flags=re.M)]
    assert not missing, f"docs/architecture.md does not name {missing}"


def test_repository_paths_named_exist():
    """A file or folder of the repository named in README.md or docs/*.md (`spare_twin/...`, `models/...`,
    ...) is there; names with placeholders (NAME, <cam>, *) are not checked."""
    named = re.compile(r"`((?:spare_twin|models|cad|capture|tests|scripts)/[\w./-]*)`")
    missing = []
    for page in [README, *sorted((REPO / "docs").glob("*.md"))]:
        for path in named.findall(page.read_text()):
            if not re.search(r"[A-Z]{3,}|[*<{]", path) and not (REPO / path).exists():
                missing.append(f"{page.relative_to(REPO)}: {path}")
    assert not missing, missing
