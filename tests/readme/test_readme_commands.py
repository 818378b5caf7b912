"""Every command in README.md and plugin/README.md runs as written (issue #23).

The fenced shell blocks are read from the two files at collection time, so a changed block is
a changed test. Each block runs with bash, as a reader would paste it, in a copy of the
checkout (its tracked files; its Python packages linked) beside ``../shared`` (a link to the
real one), with the project's ``.venv`` linked in and first on ``PATH`` (what
``. .venv/bin/activate`` does) and ``~/printability-venv`` linked to it (the plug-in's
instructions install there).

A command that cannot run here is replaced by ``:`` with its reason, listed in :data:`SKIP`:
the installs (the network; the test runs in the installed ``.venv``) and ``scripts/test``
(the whole suite, this test among it). Background jobs a block leaves running are stopped
when it ends. Files a command names as its output (``--out``, ``-o``, ``--json``) must
exist afterwards, and so must those the text around the block promises
(:data:`PROMISED_FILES`). The README's Python block runs too, and the slicer's
post-processing line of plugin/README.md runs as the slicer runs it: with the path of a
G-code file appended.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
DOCS = ("README.md", "plugin/README.md")
SHELLS = ("bash", "sh", "shell")

#: Commands that do not run here, and why (a regular expression on one command).
SKIP: tuple[tuple[str, str], ...] = (
    (r"^python3 -m venv\b", "creates a virtual environment: the test runs in the project's "
                            "installed .venv"),
    (r"\bpip install\b", "installs from the package index (the network)"),
    (r"^scripts/test\b", "runs the whole test suite, this test among it (CI runs it through "
                         ".ci/run)"),
)

#: Blocks that take long (a regular expression on the block): marked slow, with why.
SLOW: tuple[tuple[str, str], ...] = (
    (r"printability warmup", "compiles every kernel when the cache is cold (about a minute)"),
)

#: Files the text around a block promises (a command's substring -> paths).
PROMISED_FILES: dict[str, tuple[str, ...]] = {
    "printability demo": ("printability-demo/report.html",),
}

#: The slicer's post-processing line: a block of plugin/README.md without a language.
SLICER_LINE = re.compile(r"^/home/me/printability-venv/bin/printability-postprocess\s")


@dataclass(frozen=True)
class Block:
    doc: str
    line: int
    lang: str
    text: str

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"


def fenced_blocks(doc: str) -> list[Block]:
    """The fenced code blocks of a Markdown file, with their first line and language."""
    text = (ROOT / doc).read_text(encoding="utf-8")
    out = []
    for m in re.finditer(r"^```([\w-]*)[^\n]*\n(.*?)^```", text, re.M | re.S):
        out.append(Block(doc, text.count("\n", 0, m.start()) + 1, m.group(1), m.group(2)))
    return out


def runnable_blocks() -> list[Block]:
    return [b for doc in DOCS for b in fenced_blocks(doc)
            if b.lang in SHELLS or b.lang == "python" or SLICER_LINE.match(b.text)]


def commands(text: str) -> list[str]:
    """The block's logical lines: continuations joined, comment-only lines dropped."""
    out: list[str] = []
    pending = ""
    for raw in text.splitlines():
        line = pending + raw
        if line.rstrip().endswith("\\"):
            pending = line.rstrip()[:-1] + " "
            continue
        pending = ""
        if line.strip() and not line.lstrip().startswith("#"):
            out.append(line)
    return out


def skip_reason(command: str) -> str | None:
    cmd = command.strip()
    for pattern, reason in SKIP:
        if re.search(pattern, cmd):
            return reason
    return None


def script_of(block: Block) -> tuple[str, list[str]]:
    """The bash script a block runs as, and the skipped commands with their reasons."""
    lines, skipped = [], []
    for command in commands(block.text):
        # `a && b && c`: each part on its own, so the install is skipped and the demo runs
        parts = [p.strip() for p in re.split(r"\s&&\s", command)] if "&&" in command \
            else [command]
        for part in parts:
            reason = skip_reason(part)
            if reason is None:
                lines.append(part)
            else:
                skipped.append(f"{part!r}: {reason}")
                lines.append(f": skipped: {shlex.quote(part)}")
    return "\n".join(lines) + "\n", skipped


def outputs(script: str) -> list[str]:
    """Files the commands name as their output."""
    found = re.findall(r"(?:--out|-o|--output|--json)\s+(\S+)", script)
    for needle, paths in PROMISED_FILES.items():
        if needle in script:
            found += paths
    return [f for f in found if not f.startswith(("$", "-"))]


def _packages() -> set[str]:
    """The checkout's top-level Python packages."""
    return {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()}


@pytest.fixture()
def checkout(tmp_path):
    """A copy of the checkout's tracked files, ``../shared`` and ``.venv`` linked in.

    The Python packages are links to the checkout's own: a process started in the copy
    (the analysis's worker processes import from the current folder) then runs the tree's
    code with its compiled kernels, instead of compiling a copy's for a minute.
    """
    copy = tmp_path / "main"
    copy.mkdir()
    packages = _packages()
    for name in packages:
        (copy / name).symlink_to(ROOT / name, target_is_directory=True)
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    if listed.returncode == 0:
        for rel in filter(None, listed.stdout.decode().split("\0")):
            src = ROOT / rel
            if src.is_file() and Path(rel).parts[0] not in packages:
                (copy / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(src, copy / rel)
    else:  # not a git checkout (an unpacked archive): the tree without what is built
        shutil.copytree(ROOT, copy, symlinks=True, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns(".git", ".venv", "build", "__pycache__",
                                                      "*.egg-info", ".pytest_cache",
                                                      *packages))
    venv = Path(sys.prefix)
    (copy / ".venv").symlink_to(venv)
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    home = tmp_path / "home"
    home.mkdir()
    (home / "printability-venv").symlink_to(venv)
    return copy


def environment(checkout: Path, block: Block) -> dict[str, str]:
    """The reader's shell: the venv first on PATH, a private socket folder, and a home of
    its own for the blocks that use ``~`` (where ``~/printability-venv`` is the venv)."""
    import matplotlib

    venv_bin = Path(sys.prefix) / "bin"
    env = {k: v for k, v in os.environ.items()
           if k not in ("PRINTABILITY_SERVER", "PYTHONPATH", "COLUMNS")}
    env.update(PATH=f"{venv_bin}{os.pathsep}{env.get('PATH', '')}", VIRTUAL_ENV=sys.prefix,
               MPLBACKEND="Agg",
               # matplotlib's font cache as it is (a new home would rebuild it: seconds)
               MPLCONFIGDIR=matplotlib.get_cachedir(),
               # a private, short socket folder: no server of the developer's answers
               XDG_RUNTIME_DIR=tempfile.mkdtemp(prefix="pr-", dir="/tmp"))
    if "~" in block.text or "/home/me/" in block.text:
        env["HOME"] = str(checkout.parent / "home")
    return env


def run_bash(script: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    wrapped = ("set -e\n"
               "trap 'kill $(jobs -p) 2>/dev/null || true; wait 2>/dev/null || true' EXIT\n"
               + script)
    return subprocess.run(["bash", "-c", wrapped], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=900)


def params() -> list:
    out = []
    for b in runnable_blocks():
        marks = [pytest.mark.slow for pattern, _ in SLOW if re.search(pattern, b.text)]
        out.append(pytest.param(b, id=b.id, marks=marks))
    return out


def test_the_documents_have_runnable_blocks():
    blocks = runnable_blocks()
    assert {b.doc for b in blocks} == set(DOCS)
    # the README's two fresh-machine commands are among them, unchanged in meaning
    readme = "\n".join(b.text for b in blocks if b.doc == "README.md")
    assert ("python3 -m venv .venv && .venv/bin/pip install -e '.[all]' && "
            ".venv/bin/printability demo") in readme
    assert re.search(r"^scripts/test$", readme, re.M)


@pytest.mark.parametrize("block", params())
def test_block_runs_as_written(block: Block, checkout: Path):
    env = environment(checkout, block)
    try:
        if block.lang == "python":
            p = subprocess.run([sys.executable, "-c", block.text], cwd=checkout, env=env,
                               capture_output=True, text=True, timeout=300)
            assert p.returncode == 0, p.stderr
            return
        if SLICER_LINE.match(block.text):
            # the slicer appends the path of the G-code it just wrote
            gcode = checkout / "exported.gcode"
            sample = SHARED / "data" / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode"
            if not sample.is_file():
                pytest.skip(f"no sample G-code at {sample}")
            shutil.copy(sample, gcode)
            line = block.text.strip().replace("/home/me/", env["HOME"].rstrip("/") + "/")
            p = run_bash(f"{line} {shlex.quote(str(gcode))}\n", checkout, env)
            assert p.returncode == 0, p.stdout + p.stderr
            from printability.postprocess import already_processed

            assert already_processed(gcode.read_bytes()), "the slicer's file was not rewritten"
            return
        script, skipped = script_of(block)
        if "../shared" in script and not SHARED.is_dir():
            pytest.skip(f"the block reads ../shared, not found at {SHARED}")
        p = run_bash(script, checkout, env)
        assert p.returncode == 0, (f"{block.id} failed (skipped: {skipped}):\n{script}\n"
                                   f"--- stdout\n{p.stdout[-3000:]}\n--- stderr\n"
                                   f"{p.stderr[-3000:]}")
        for rel in outputs(script):
            assert (checkout / rel).exists(), f"{block.id}: {rel} was not written"
    finally:
        shutil.rmtree(env["XDG_RUNTIME_DIR"], ignore_errors=True)


def test_skipped_commands_are_listed_with_their_reasons():
    """Only the installs and the test suite are skipped, and each says why."""
    skipped = [s for b in runnable_blocks() if b.lang in SHELLS for s in script_of(b)[1]]
    assert skipped, "nothing is skipped: update this test's expectations"
    for s in skipped:
        assert re.search(r"python3 -m venv|pip install|scripts/test", s), s
        assert ": " in s
