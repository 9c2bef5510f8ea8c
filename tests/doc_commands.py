"""The shell commands the docs give, read out of their ```sh / ```bash / ```console blocks, for
the tests that check them against the command line (tests/test_docs_commands.py) and run them
(tests/micam/test_docs_import.py).

How a block is read:

- a fence may be indented (a block inside a list item); its lines are taken without that indent;
- a line ending in `\\` continues on the next; `# ...` to the end of a line is a comment; a
  line that is only `...` (the doc eliding steps) is no command;
- a prompt (`$ `, `head$ `) and `sudo` are dropped, so are leading `NAME=value` assignments
  (kept in `DocCommand.env`); `&&`, `;`, `|` and a trailing `&` between words separate commands;
- the program's path is dropped for micam (`/opt/micam/bin/micam`, `.venv/bin/micam`).

The docs write usage synopses inside these blocks too; `synopsis_variants` expands them:
`[...]` an optional part, `(a | b)` and `[a | b]` alternatives, `a|b|c` one word's alternatives,
`WORD[=MORE]` inside a word optional text, `WORD...` and a lone `...` repetition / elision.
Placeholders (words in capitals such as DIR, FILE, SESSION, SPEC.toml, `<session>`) stay as
they are: argparse takes them as paths or names. Only those an option's type checks are
replaced, by `PLACEHOLDER_VALUES` (a count N, a fold count K, an angle DEG, ...); a new typed
placeholder in a doc fails the test until it is added there.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHELL_FENCE = re.compile(r"^(\s*)```(sh|bash|console|shell)\s*$")

# typed placeholders: what argparse's type of their option accepts in their place
PLACEHOLDER_VALUES = {"N": "2", "K": "5", "DEG": "1.0", "POSE:SPEAKER": "1:2",
                      "SERIAL,...": "36001,36002"}
SEPARATORS = ("&&", ";", "|", "&")


@dataclass(frozen=True)
class DocCommand:
    """One command of a doc's shell block: where it is and its words, as a shell splits them."""

    doc: str  # the doc's path in the repository
    line: int  # 1-based line of the command's first line
    words: tuple[str, ...]
    env: tuple[tuple[str, str], ...] = field(default=())
    section: str = ""  # the heading it is under: a world of its own (the boards, a sound card)

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"

    @property
    def program(self) -> str:
        return self.words[0]


def shell_blocks(markdown: str) -> list[tuple[int, list[str], str]]:
    """Each shell block as (line number of its first line, its lines without the indent, the
    `##` heading it is under)."""
    lines = markdown.splitlines()
    blocks, i, heading = [], 0, ""
    while i < len(lines):
        if lines[i].startswith("## "):
            heading = lines[i][3:].strip()
        if fence := SHELL_FENCE.match(lines[i]):
            indent, body, start = len(fence.group(1)), [], i + 2
            i += 1
            while not lines[i].strip().startswith("```"):
                body.append(lines[i][indent:])
                i += 1
            blocks.append((start, body, heading))
        i += 1
    return blocks


def doc_commands(doc: Path) -> list[DocCommand]:
    """Every command of `doc`'s shell blocks, in order (see the module's docstring)."""
    name = str(doc.resolve().relative_to(REPO))
    found = []
    for start, body, heading in shell_blocks(doc.read_text()):
        n = 0
        while n < len(body):
            first, text = start + n, body[n]
            while text.endswith("\\") and n + 1 < len(body):
                n += 1
                text = text[:-1] + " " + body[n]
            n += 1
            text = re.sub(r"^\s*\w*\$\s+", "", text)  # a prompt
            try:
                words_read = shlex.split(text, comments=True)
            except ValueError as exc:  # an unclosed quote: a doc's typo, named by its line
                raise ValueError(f"{name}:{first}: {exc}: {text}") from None
            for words in _split(words_read):
                if command := _command(name, first, words):
                    found.append(replace(command, section=heading))
    return found


def inline_micam_spans(doc: Path) -> list[tuple[int, list[str]]]:
    """Each `micam ...` code span of `doc`'s prose (an option named in a sentence, often without
    its value): (its line, its words after `micam`)."""
    text = doc.read_text()
    return [(text.count("\n", 0, m.start()) + 1, m.group(1).split())
            for m in re.finditer(r"`micam\s([^`]+)`", text)]


def _split(words: list[str]) -> list[list[str]]:
    """`words` cut at the shell's command separators; the synopsis' `|` inside brackets and
    parentheses is an alternative, not a pipe."""
    parts: list[list[str]] = [[]]
    depth = 0
    for word in words:
        depth += word.count("[") + word.count("(") - word.count("]") - word.count(")")
        if word in SEPARATORS and depth <= 0:
            parts.append([])
        else:
            parts[-1].append(word)
    return [p for p in parts if p]


def _command(doc: str, line: int, words: list[str]) -> DocCommand | None:
    env: list[tuple[str, str]] = []
    while words and (words[0] == "sudo" or re.fullmatch(r"[A-Z_]+=\S*", words[0])):
        if words[0] != "sudo":
            name, value = words[0].split("=", 1)
            env.append((name, value))
        words = words[1:]
    if not words or words == ["..."]:
        return None
    if words[0].endswith("/micam"):
        words = ["micam", *words[1:]]
    return DocCommand(doc, line, tuple(words), tuple(env))


def synopsis_variants(words: tuple[str, ...]) -> list[list[str]]:
    """The concrete command lines a synopsis stands for: variant k takes the k-th alternative
    at every choice (the last where there are fewer) and every optional part; one more variant
    leaves every optional part out. Together they use every alternative and option once."""
    tree = _parse(_tokens(words))
    width = _width(tree)
    variants = [_expand(tree, k, True) for k in range(width)] + [_expand(tree, 0, False)]
    unique: list[list[str]] = []
    for v in variants:
        v = [PLACEHOLDER_VALUES.get(w, w) for w in v]
        if v not in unique:
            unique.append(v)
    return unique


# a synopsis' tree: ("seq", [nodes]), ("opt", alternatives), ("req", alternatives),
# ("word", [alternative words]); alternatives are lists of "seq" nodes
Node = tuple[str, list[Any]]


def _tokens(words: tuple[str, ...]) -> list[str]:
    tokens = []
    for word in words:
        head = word[:len(word) - len(word.lstrip("[("))]
        core = word[len(head):]
        tail = core[len(core.rstrip("])")):]
        while tail and tail[0] == "]" and core[:len(core) - len(tail)].count("[") > 0:
            tail = tail[1:]  # `NAME[=ARGS]`'s own bracket, not a group's
        core = core[:len(core) - len(tail)]
        tokens += [*head, *([core] if core else []), *tail]
    return tokens


def _parse(tokens: list[str]) -> Node:
    node, rest = _seq(tokens)
    assert not rest, f"unbalanced synopsis near {rest}"
    return node


def _seq(tokens: list[str]) -> tuple[Node, list[str]]:
    items: list[Node] = []
    while tokens and tokens[0] not in ("|", "]", ")"):
        token, tokens = tokens[0], tokens[1:]
        if token in ("[", "("):
            alternatives = []
            while True:
                node, tokens = _seq(tokens)
                alternatives.append(node)
                closing, tokens = tokens[0], tokens[1:]
                if closing != "|":
                    break
            items.append(("opt" if token == "[" else "req", alternatives))
        elif token != "...":
            items.append(("word", _word_alternatives(token)))
    return ("seq", items), tokens


def _word_alternatives(word: str) -> list[str]:
    word = re.sub(r"\[([^\]]*)\]", r"\1", word)  # NAME[=ARGS]: the longer form
    if word.endswith("...") and len(word) > 3 and not word.endswith(",..."):
        word = word[:-3]  # SESSION...: one of them
    if "|" in word and not word.startswith(("<", "tcp:")):
        return word.split("|")
    return [word]


def _width(node: Node) -> int:
    kind, parts = node
    if kind == "word":
        return len(parts)
    if kind == "seq":
        return max([_width(p) for p in parts], default=1)
    return max(len(parts), *(_width(p) for p in parts))


def _expand(node: Node, k: int, optional: bool) -> list[str]:
    kind, parts = node
    if kind == "word":
        return [parts[min(k, len(parts) - 1)]]
    if kind == "seq":
        return [w for p in parts for w in _expand(p, k, optional)]
    if kind == "opt" and not optional:
        return []
    return _expand(parts[min(k, len(parts) - 1)], k, optional)
