#!/usr/bin/env python3
"""Checks the documentation so that it cannot rot unnoticed (the ctest `docs.check`).

1. Every relative link and image in README.md, CONTRIBUTING.md and docs/*.md must name an existing file or
   folder. A `#anchor` into a Markdown file must name one of its headings (GitHub's heading ids).
2. Fenced code blocks whose info string is `sh test` run with bash (`-e -o pipefail`), from the repository
   root, with BIN (the build's bin folder) and MESHES (CGAL's sample meshes) in the environment. Blocks tagged
   `python test` run with --python, from the repository root, with PYTHONPATH=--pythonpath (the build's
   python/ folder, where the package voxfmt is assembled). A block fails on a non-zero exit.
3. The table of the bake's stages in docs/cli.md (between `<!-- bake-stages -->` markers) must list the stages of
   `kBakeStages` (tools/bake/include/voxfmt/bake/bake.h), the one list the bake's timings and progress use: the
   same names, in the same order, each within the same stage, with the same progress share.

Only blocks that take seconds are tagged: the rest of the docs is plain `sh`, `python`, `cpp`, ...

    python3 scripts/check-docs.py                          # after bash scripts/build.sh
    python3 scripts/check-docs.py --links-only             # no build needed
    python3 scripts/check-docs.py --bin build-shared/bin --pythonpath build-shared/python

Python standard library only.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,}|~{3,})(?P<info>.*)$")
# [text](target "title") and ![alt](target): the target up to whitespace or the closing parenthesis (one level
# of parentheses inside is allowed); autolinks and bare URLs are not relative links.
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?(?P<target>(?:[^()\s<>]|\([^()\s]*\))*)>?(?:\s+[\"'(][^)]*)?\s*\)")
REFERENCE_DEF = re.compile(r"^ {0,3}\[[^\]]+\]:[ \t]*<?(?P<target>[^\s<>]+)>?(?:[ \t]+.*)?$", re.MULTILINE)
HTML_SRC = re.compile(r"<(?:img|a)\b[^>]*?\b(?:src|href)\s*=\s*\"(?P<target>[^\"]+)\"", re.IGNORECASE)
INLINE_CODE = re.compile(r"(`+)(?:.+?)\1")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


@dataclass
class Block:
    file: Path
    line: int  # 1-based line of the opening fence
    kind: str  # "sh" or "python"
    code: str


def doc_files() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "CONTRIBUTING.md"]
    files += sorted((ROOT / "docs").glob("*.md"))
    return [f for f in files if f.exists()]


def split(path: Path) -> tuple[list[tuple[int, str]], list[Block]]:
    """The file's prose lines (number, text) outside fenced blocks, and its tested blocks."""
    prose: list[tuple[int, str]] = []
    blocks: list[Block] = []
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m or (m.group("fence")[0] == "`" and "`" in m.group("info")):
            prose.append((i + 1, lines[i]))
            i += 1
            continue
        fence, info, start = m.group("fence"), m.group("info").strip(), i
        body: list[str] = []
        i += 1
        while i < len(lines):
            close = FENCE.match(lines[i])
            if close and close.group("fence")[0] == fence[0] and len(close.group("fence")) >= len(fence) \
                    and not close.group("info").strip():
                break
            body.append(lines[i])
            i += 1
        else:
            raise SystemExit(f"{path.relative_to(ROOT)}:{start + 1}: code block never closed")
        i += 1  # the closing fence
        words = info.split()
        if len(words) >= 2 and words[1] == "test":
            if words[0] in ("sh", "bash", "shell"):
                blocks.append(Block(path, start + 1, "sh", "\n".join(body) + "\n"))
            elif words[0] == "python":
                blocks.append(Block(path, start + 1, "python", "\n".join(body) + "\n"))
            else:
                raise SystemExit(f"{path.relative_to(ROOT)}:{start + 1}: '{info}': only `sh test` and "
                                 "`python test` blocks can be run")
    return prose, blocks


def github_anchor(heading: str) -> str:
    """GitHub's id of a heading: markup dropped, lower case, punctuation removed, spaces to hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # links: their text
    text = re.sub(r"<[^>]+>", "", text)
    text = text.replace("`", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors_of(path: Path, cache: dict[Path, set[str]]) -> set[str]:
    if path not in cache:
        prose, _ = split(path)
        seen: dict[str, int] = {}
        ids: set[str] = set()
        for _, line in prose:
            m = re.match(r"^ {0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
            if not m:
                continue
            base = github_anchor(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            ids.add(base if n == 0 else f"{base}-{n}")
        for _, line in prose:  # explicit <a id="..."> / <a name="...">
            ids.update(re.findall(r"<a\s+(?:id|name)=\"([^\"]+)\"", line))
        cache[path] = ids
    return cache[path]


def check_links(files: list[Path]) -> list[str]:
    errors: list[str] = []
    cache: dict[Path, set[str]] = {}
    count = 0
    for path in files:
        prose, _ = split(path)
        # The prose as one text (fenced blocks blanked, so line numbers stay), `code` spans blanked: a link's
        # text may wrap onto the next line.
        lines = path.read_text(encoding="utf-8").splitlines()
        kept = {number for number, _ in prose}
        text = "\n".join(INLINE_CODE.sub(lambda m: " " * len(m.group(0)), line) if n + 1 in kept else ""
                         for n, line in enumerate(lines))
        found = [(m.start(), m.group("target")) for m in INLINE_LINK.finditer(text)]
        found += [(m.start(), m.group("target")) for m in HTML_SRC.finditer(text)]
        found += [(m.start(), m.group("target")) for m in REFERENCE_DEF.finditer(text)]
        for offset, target in found:
            if not target or SCHEME.match(target) or target.startswith("//"):
                continue  # web links are not checked (no network in CI)
            count += 1
            where = f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, offset) + 1}"
            file_part, _, anchor = target.partition("#")
            resolved = (path.parent / file_part).resolve() if file_part else path
            if file_part and not resolved.exists():
                errors.append(f"{where}: link to '{target}': {file_part} does not exist")
                continue
            if anchor and resolved.is_file() and resolved.suffix == ".md":
                if anchor not in anchors_of(resolved, cache):
                    name = resolved.relative_to(ROOT) if resolved.is_relative_to(ROOT) else resolved
                    errors.append(f"{where}: link to '{target}': no heading '#{anchor}' in {name}")
    print(f"check-docs: {count} relative links in {len(files)} files", file=sys.stderr)
    return errors


def run_blocks(blocks: list[Block], args: argparse.Namespace) -> list[str]:
    errors: list[str] = []
    env = dict(os.environ)
    env["BIN"] = str(Path(args.bin).resolve())
    env["MESHES"] = str(Path(args.meshes).resolve())
    env["PYTHONPATH"] = os.pathsep.join(p for p in [str(Path(args.pythonpath).resolve()),
                                                    os.environ.get("PYTHONPATH", "")] if p)
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    for block in blocks:
        where = f"{block.file.relative_to(ROOT)}:{block.line}"
        if block.kind == "python" and args.no_python:
            print(f"check-docs: {where}: python block skipped (--no-python)", file=sys.stderr)
            continue
        with tempfile.NamedTemporaryFile("w", suffix=".sh" if block.kind == "sh" else ".py", delete=False) as f:
            f.write(block.code)
            script = f.name
        command = ["bash", "-e", "-o", "pipefail", script] if block.kind == "sh" else [args.python, script]
        start = time.monotonic()
        try:
            run = subprocess.run(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 text=True, timeout=args.timeout)
            status, output = run.returncode, run.stdout
        except subprocess.TimeoutExpired as e:
            status = f"timeout after {args.timeout} s"
            output = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
        finally:
            os.unlink(script)
        took = time.monotonic() - start
        if status != 0:
            tail = "\n".join("    | " + line for line in output.rstrip().splitlines()[-25:])
            errors.append(f"{where}: `{block.kind} test` block failed ({status}):\n{tail}")
        else:
            print(f"check-docs: {where}: {block.kind} block ok ({took:.1f} s)", file=sys.stderr)
    return errors


STAGE_ROW = re.compile(r'\{BakeStage::(\w+), "([^"]+)", BakeStage::(\w+), ([-0-9.]+)\}')


def check_stage_table() -> list[str]:
    header = ROOT / "tools/bake/include/voxfmt/bake/bake.h"
    rows = STAGE_ROW.findall(header.read_text())
    if not rows:
        return [f"{header.relative_to(ROOT)}: no kBakeStages rows found"]
    name_of = {enum: name for enum, name, _, _ in rows}
    expected = []
    for enum, name, within, share in rows:
        start = float(share)
        expected.append((name, "" if within == enum else name_of[within],
                         f"{round(start * 100)} %" if start >= 0 else ""))
    doc = ROOT / "docs/cli.md"
    text = doc.read_text()
    match = re.search(r"<!-- bake-stages -->(.*?)<!-- /bake-stages -->", text, re.S)
    if not match:
        return [f"{doc.relative_to(ROOT)}: no table between <!-- bake-stages --> markers"]
    documented = []
    for line in match.group(1).splitlines():
        cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] not in ("stage", "") and not set(cells[0]) <= set("-: "):
            documented.append(tuple(cells))
    if documented != expected:
        return [f"{doc.relative_to(ROOT)}: the bake-stages table {documented} is not kBakeStages {expected}"]
    return []


def default_python() -> str:
    venv = ROOT / ".venv" / "bin" / "python"  # scripts/install-deps.sh; the build's Python_EXECUTABLE
    return str(venv) if venv.exists() else sys.executable


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bin", default=str(ROOT / "build" / "bin"), help="the build's bin folder (env BIN)")
    parser.add_argument("--meshes", default=str(ROOT / "build" / "cgal-data" / "data" / "meshes"),
                        help="CGAL's sample meshes (env MESHES)")
    parser.add_argument("--python", default=default_python(), help="interpreter of `python test` blocks")
    parser.add_argument("--pythonpath", default=str(ROOT / "build" / "python"),
                        help="where the package voxfmt is importable (prepended to PYTHONPATH)")
    parser.add_argument("--no-python", action="store_true", help="skip `python test` blocks (no Python package)")
    parser.add_argument("--links-only", action="store_true", help="check the links, run nothing")
    parser.add_argument("--timeout", type=float, default=120, help="seconds a block may take")
    args = parser.parse_args()

    files = doc_files()
    errors = check_links(files) + check_stage_table()
    if not args.links_only:
        blocks = [b for f in files for b in split(f)[1]]
        errors += run_blocks(blocks, args)
    for error in errors:
        print(f"check-docs: {error}", file=sys.stderr)
    print(f"check-docs: {'FAILED, ' + str(len(errors)) + ' problem(s)' if errors else 'ok'}", file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
