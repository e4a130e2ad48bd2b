"""The user documentation against the real CLI: every `illum` command and flag the README and
docs/ show exists in the argument parser, and every relative link points to a file that exists.

Text between `<!-- PENDING(name): note -->` and `<!-- /PENDING(name) -->` documents a feature another
branch is adding; it is left out until the lead removes the markers after merging, and is then
checked like the rest."""

from __future__ import annotations

import argparse
import glob
import os
import re

import pytest

from renderer.cli import build_parser

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOCS = ["README.md", *sorted(os.path.relpath(p, ROOT) for p in glob.glob(os.path.join(ROOT, "docs", "*.md")))]
PENDING = re.compile(r"<!-- PENDING\((?P<name>[\w-]+)\)[^>]*-->.*?<!-- /PENDING\((?P=name)\) -->", re.S)
COMMAND = re.compile(r"(?<![\w/.-])illum ([a-z]+)\b")
FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


def read(rel: str) -> str:
    with open(os.path.join(ROOT, rel), encoding="utf-8") as fh:
        return PENDING.sub("", fh.read())


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def options(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


def command_lines(text: str):
    """(subcommand, the text that follows it up to the end of its command) for each `illum X`
    in code blocks and inline code; a line ending in nothing but a flag list continues a
    synopsis, so indented continuation lines of a fenced block count too."""
    for block in re.findall(r"```[^\n]*\n(.*?)```", text, re.S):
        current = None
        for line in block.splitlines():
            m = COMMAND.search(line)
            if m:
                current = m.group(1)
                yield current, line[m.end():]
            elif current is not None and line.startswith(" "):
                yield current, line
            else:
                current = None
    for span in re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.S)):
        m = COMMAND.search(span)
        if m:
            yield m.group(1), span[m.end():]


@pytest.mark.parametrize("doc", DOCS)
def test_commands_and_their_flags_exist(doc):
    subs = subcommands()
    top = options(build_parser())
    seen = 0
    for cmd, rest in command_lines(read(doc)):
        assert cmd in subs, f"{doc}: `illum {cmd}` is not a subcommand ({', '.join(subs)})"
        known = options(subs[cmd]) | top
        for flag in FLAG.findall(rest.split("#")[0]):
            assert flag in known, f"{doc}: `illum {cmd}` has no flag {flag}"
        seen += 1
    if doc == "README.md":
        assert seen >= 10, "the README shows the commands users run"


def test_every_flag_the_readme_names_exists_somewhere():
    """Flags named in prose and tables (not only in commands) belong to some subcommand."""
    subs = subcommands()
    known = options(build_parser()).union(*(options(p) for p in subs.values()))
    text = read("README.md")
    unknown = sorted(set(FLAG.findall(text)) - known)
    assert not unknown, f"README.md names flags the CLI does not have: {unknown}"


def test_pending_markers_are_balanced():
    for doc in DOCS:
        with open(os.path.join(ROOT, doc), encoding="utf-8") as fh:
            raw = fh.read()
        opened = re.findall(r"<!-- PENDING\(([\w-]+)\)[^>]*-->", raw)
        closed = re.findall(r"<!-- /PENDING\(([\w-]+)\) -->", raw)
        assert opened == closed, f"{doc}: unbalanced PENDING markers {opened} / {closed}"


@pytest.mark.parametrize("doc", DOCS)
def test_relative_links_resolve(doc):
    text = read(doc)
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = os.path.normpath(os.path.join(ROOT, os.path.dirname(doc), target.split("#")[0]))
        assert os.path.exists(path), f"{doc}: link {target} points to nothing"


def test_readme_stays_a_guide():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as fh:
        text = fh.read()
    assert len(text.splitlines()) <= 250
    assert "make demo" in text and "make test" in text
    assert "session" not in text.lower()
