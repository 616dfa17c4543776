"""The documentation's commands and links, checked against the code without running anything.

Every shell line in a fenced code block of ``README.md`` and ``doc/*.md`` that calls one
of the project's tools is checked:

* a console script (``sfs-...``, also as ``.venv/bin/sfs-...``) must be declared in
  ``setup.py``; when its module in ``sfs_ros.cli`` has a ``build_parser()``, the line's
  arguments must parse with it (placeholders such as ``INPUT`` or ``OUT.ply`` parse as
  paths). A synopsis line (optional parts in ``[...]``) cannot parse as a whole: each
  option it names must be one of the parser's, and a plain command must be given too.
  Node executables (``sfs-motor --ros-args ...``) have no parser of ours: the script
  must exist;
* ``python -m sfs_ros...`` / ``python -m bench...``: the module must exist (and parse,
  for a ``sfs_ros.cli`` tool); ``python -m pytest`` arguments naming test files must exist;
* ``bash scripts/...``: the script must exist.

Every relative link between the markdown files must resolve to a file (and a ``#anchor``
to a heading of the target, by GitHub's rule for heading anchors); README.md stays short.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "doc").glob("*.md"))]
README_MAX_LINES = 200
SHELL_LANGUAGES = {"", "sh", "bash", "shell", "console"}

FENCE = re.compile(r"^(```+|~~~+)\s*([\w+-]*)")


def fenced_blocks(path: Path):
    """(language, first line number, lines) of every fenced code block in ``path``."""
    lines = path.read_text(encoding="utf-8").splitlines()
    block, language, start, fence = None, "", 0, ""
    for number, line in enumerate(lines, 1):
        match = FENCE.match(line.strip())
        if block is None:
            if match:
                block, fence, language, start = [], match.group(1), match.group(2).lower(), number + 1
        elif line.strip().startswith(fence) and not line.strip().strip(fence[0]):
            yield language, start, block
            block = None
        else:
            block.append(line)
    assert block is None, f"{path.name}: a code block opened at line {start - 1} is not closed"


def shell_lines(path: Path):
    """(line number, text) of every shell line, continuation lines joined."""
    for language, start, block in fenced_blocks(path):
        if language not in SHELL_LANGUAGES:
            continue
        pending, first = "", 0
        for offset, line in enumerate(block):
            text = line.rstrip()
            if not pending:
                first = start + offset
                text = text.lstrip()
                if text.startswith("$ "):
                    text = text[2:]
            if text.endswith("\\"):
                pending += text[:-1] + " "
                continue
            yield first, pending + text
            pending = ""
        if pending:
            yield first, pending


def console_scripts() -> dict[str, str]:
    """Console script name -> module, from setup.py's entry points."""
    text = (ROOT / "setup.py").read_text(encoding="utf-8")
    found = dict(re.findall(r'"(sfs-[\w-]+)\s*=\s*([\w.]+):main"', text))
    assert found, "no console scripts found in setup.py"
    return found


SCRIPTS = console_scripts()
PROJECT_CALL = re.compile(r"^(?:\S*/)?(sfs-[\w-]+)$")
PYTHON = re.compile(r"^(?:\S*/)?python3?$")


def project_commands():
    """Every documented call of a project tool: (file:line, words)."""
    found = []
    for path in DOCS:
        for number, line in shell_lines(path):
            try:
                words = shlex.split(line, comments=True)
            except ValueError as error:
                words = [line]
                if re.search(r"\bsfs-|-m (sfs_ros|bench)\b", line):
                    raise AssertionError(
                        f"{path.name}:{number}: not a shell line: {error}") from None
            if not words:
                continue
            head = words[0]
            is_project = (PROJECT_CALL.match(head)
                          or (PYTHON.match(head) and len(words) > 2 and words[1] == "-m")
                          or (head == "bash" and len(words) > 1 and words[1].startswith("scripts/")))
            if is_project:
                found.append(pytest.param(words, id=f"{path.relative_to(ROOT)}:{number}"))
    return found


COMMANDS = project_commands()


def is_synopsis(argv) -> bool:
    return any(word.startswith("[") or word.endswith("]") or word == "|" for word in argv)


def parser_of(module_name: str):
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        # sfs-demo and sfs-replay import rclpy: without ROS 2's Python packages
        # (scripts/setup.sh installs them) their parsers cannot be built.
        if (error.name or "").split(".")[0] in ("rclpy", "rosidl_runtime_py") or \
                (error.name or "").endswith(("_msgs", "_srvs")):
            pytest.skip(f"{module_name} needs ROS 2's Python packages ({error.name})")
        raise
    build = getattr(module, "build_parser", None)
    return build() if build else None


def check_parses(parser, argv, where: str) -> None:
    if is_synopsis(argv):
        known = set(parser._option_string_actions)
        options = set()
        for word in argv:
            for option in re.findall(r"(?<![\w-])(--?[A-Za-z][\w-]*)", word):
                options.add(option)
        unknown = sorted(options - known)
        assert not unknown, f"{where}: the synopsis names options {parser.prog} does not have: {unknown}"
        return
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            parser.parse_args(argv)
        except SystemExit as stop:
            assert stop.code == 0, f"{where}: {parser.prog} {shlex.join(argv)} does not parse: " \
                                   f"{err.getvalue().strip()}"


@pytest.mark.parametrize("words", COMMANDS)
def test_documented_command_is_real(words, request):
    where = request.node.callspec.id
    head = words[0]
    if head == "bash":
        assert (ROOT / words[1]).is_file(), f"{where}: no script {words[1]}"
        return
    match = PROJECT_CALL.match(head)
    if match:
        script = match.group(1)
        assert script in SCRIPTS, f"{where}: {script} is not a console script in setup.py"
        module, argv = SCRIPTS[script], words[1:]
    else:
        module, argv = words[2], words[3:]
        if module == "pytest":
            for word in argv:
                if word.startswith("test/"):
                    assert (ROOT / word.split("::")[0]).exists(), f"{where}: no {word}"
            return
        assert module.split(".")[0] in ("sfs_ros", "bench"), f"{where}: python -m {module}"
        assert importlib.util.find_spec(module) is not None, f"{where}: no module {module}"
    if "--ros-args" in argv:
        # A node executable: its arguments are ROS's, not ours.
        assert module.startswith("sfs_ros.nodes."), f"{where}: --ros-args for {module}"
        argv = argv[:argv.index("--ros-args")]
        assert not argv, f"{where}: arguments before --ros-args: {argv}"
        return
    if module.startswith("sfs_ros.cli."):
        parser = parser_of(module)
        assert parser is not None, f"{where}: {module} has no build_parser()"
        check_parses(parser, argv, where)


def test_every_tool_with_a_synopsis_has_a_plain_example():
    """A synopsis is checked option by option only; each tool it documents also has a
    command that parses as a whole."""
    synopses, plain = set(), set()
    for param in COMMANDS:
        words = param.values[0]
        name = words[0].rsplit("/", 1)[-1]
        (synopses if is_synopsis(words) else plain).add(name)
    assert synopses <= plain, f"tools documented only by a synopsis: {sorted(synopses - plain)}"


def test_the_docs_document_commands():
    names = {param.values[0][0].rsplit("/", 1)[-1] for param in COMMANDS}
    for tool in ("sfs-reconstruct", "sfs-simulate", "sfs-demo", "sfs-cell", "sfs-replay",
                 "sfs-export", "sfs-calibrate"):
        assert tool in names, f"{tool} is in no code block of the docs"


def test_the_two_commands_come_first():
    blocks = [block for language, _, block in fenced_blocks(ROOT / "README.md")]
    first = "\n".join(blocks[0])
    assert first.index("bash scripts/demo.sh") < first.index("bash scripts/test.sh")


def github_anchor(heading: str) -> str:
    """GitHub's anchor of a heading: its text as shown (code marks, emphasis stars and
    links' targets gone; an underscore is kept, as in ``sfs_ros``), lower case, without
    punctuation but hyphens and underscores, spaces as hyphens."""
    text = re.sub(r"[`*]|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", heading.strip())
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    inside, found = False, set()
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line.strip()):
            inside = not inside
        elif not inside and line.startswith("#"):
            found.add(github_anchor(line.lstrip("#")))
    return found


LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def links():
    found = []
    for path in DOCS:
        inside = False
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if FENCE.match(line.strip()):
                inside = not inside
                continue
            if inside:
                continue
            for target in LINK.findall(line):
                if re.match(r"^[a-z]+:", target):
                    continue  # http:, mailto: ...
                found.append(pytest.param(path, target, id=f"{path.relative_to(ROOT)}:{number}:{target}"))
    return found


@pytest.mark.parametrize(("source", "target"), links())
def test_relative_link_resolves(source, target):
    file_part, _, anchor = target.partition("#")
    resolved = (source.parent / file_part).resolve() if file_part else source
    assert resolved.exists(), f"{source.name}: link to {target}: no such file"
    if anchor and resolved.suffix == ".md":
        assert anchor in anchors(resolved), \
            f"{source.name}: link to {target}: no heading with that anchor in {resolved.name}"


def test_every_doc_page_is_linked_from_the_readme():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for page in DOCS[1:]:
        assert f"(doc/{page.name}" in readme, f"README.md does not link doc/{page.name}"


def test_readme_stays_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines < README_MAX_LINES, f"README.md has {lines} lines (keep it under {README_MAX_LINES})"


def test_readme_picture_is_small():
    picture = ROOT / "doc" / "images" / "mesh.png"
    assert picture.is_file()
    assert picture.stat().st_size < 300_000


def test_documented_input_limits_match_the_code():
    from sfs_ros.core.carving.resolution import DEFAULT_MEMORY_SHARE
    from sfs_ros.core.exchange import limits

    text = (ROOT / "doc" / "reconstruct.md").read_text(encoding="utf-8")
    documented = [
        f"at most {limits.MAX_IMAGE_FILE_BYTES >> 30} GiB and at most "
        f"{limits.MAX_IMAGE_PIXELS // 1_000_000} megapixels",
        f"{limits.MAX_TEXT_FILE_BYTES >> 20} MiB",
        f"nests at most {limits.MAX_DOCUMENT_DEPTH} levels",
        {0.25: "a quarter of the machine's memory"}[DEFAULT_MEMORY_SHARE],
    ]
    for phrase in documented:
        assert phrase in " ".join(text.split()), f"doc/reconstruct.md does not say {phrase!r}"
