"""What the documentation tests share: the pages (README.md and docs/*.md), their text, the
inline code spans and fenced/indented blocks, and the parsers of ``tensegrity`` and its
subcommands."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]
CODE = re.compile(r'`([^`\n]+)`')


def text_of(page):
    return page.read_text(encoding='utf-8')


def strip_code_blocks(text):
    """Text outside fenced and indented code blocks (commands are quoted there)."""
    text = re.sub(r'```.*?```', '', text, flags=re.S)
    return '\n'.join(line for line in text.splitlines() if not line.startswith('    '))


def parsers():
    """``(name, parser)`` of ``tensegrity`` and of each of its subcommands."""
    from tensegrity_ros.cli import build_parser
    parser = build_parser()
    yield 'tensegrity', parser
    for action in parser._actions:
        if hasattr(action, 'choices') and isinstance(action.choices, dict):
            for name, sub in action.choices.items():
                yield name, sub
