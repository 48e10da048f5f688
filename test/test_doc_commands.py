"""The commands the README and docs/ show: every one is a command the CLI accepts (run from a
shell with ``.venv`` activated, on files that exist or that an earlier command writes), the
output shown after ``$ `` is what the command prints, and the programs they start are installed
in the venv."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from docs_helpers import CODE, PAGES, ROOT
from docs_helpers import parsers as _parsers
from docs_helpers import strip_code_blocks as _strip_code_blocks
from docs_helpers import text_of as _text

# A command starts with one of these programs; ``$ `` marks a command whose output follows.
SHELL = re.compile(r'^(?:\$ )?(tensegrity|tensegrity_node|python|make|rerun|bash|pip|'
                   r'\.venv/bin/[\w.-]+)(?=\s|$)')
VENV_PROGRAMS = ('tensegrity', 'tensegrity_node', 'python', 'rerun', 'pip')
ACTIVATE = '. .venv/bin/activate'
# options whose value a command writes (a file or a directory), not reads
OUTPUT_OPTIONS = ('--out', '--to-rerun', '--write-scene', '-o')
PLACEHOLDER = re.compile(r'^[A-Z][A-Z0-9_]*(\.\w+)?$|\.\.\.|[\[\]]|<\w+>')
PATHLIKE = re.compile(r'^[\w.~/-]*/[\w.-]+$'
                      r'|^[\w.-]+\.(ya?ml|mcap|rrd|json|csv|png|py|sh|parquet)$')


def _block_lines(text):
    """(line number, line) of the shell code: fenced blocks with no language or a shell one, and
    indented blocks; a command continues over lines ending with a backslash and over deeper
    indented lines that open with ``[`` (a synopsis)."""
    fenced, lang = False, ''
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith('```'):
            fenced, lang = (not fenced), line[3:].strip()
            continue
        if fenced and lang in ('', 'sh', 'bash', 'console', 'shell'):
            out.append((n, line))
        elif not fenced and line.startswith('    '):
            out.append((n, line[4:]))
    return out


def _commands(text):
    """(line number, command text, shown output lines) of every shell command in code blocks."""
    lines = _block_lines(text)
    found, i = [], 0
    while i < len(lines):
        n, line = lines[i]
        m = SHELL.match(line.strip())
        if not m or line != line.lstrip():
            i += 1
            continue
        command = line.strip()
        while command.endswith('\\') and i + 1 < len(lines):
            i += 1
            command = command[:-1] + ' ' + lines[i][1].strip()
        while i + 1 < len(lines) and lines[i + 1][1].lstrip().startswith('[') \
                and lines[i + 1][1].startswith(' ') and lines[i + 1][0] == lines[i][0] + 1:
            i += 1
            command += ' ' + lines[i][1].strip()
        output = []
        if command.startswith('$ '):
            command = command[2:]
            while i + 1 < len(lines) and lines[i + 1][0] == lines[i][0] + 1 \
                    and not lines[i + 1][1].startswith('$ '):
                i += 1
                output.append(lines[i][1])
        found.append((n, command, output))
        i += 1
    return found


def _inline_commands(text):
    """(line number, command) of inline code spans that show a ``tensegrity`` command."""
    for n, line in enumerate(_strip_code_blocks(text).splitlines(), 1):
        for span in CODE.findall(line):
            if re.match(r'tensegrity\s', span):
                yield n, span


def _tokens(command):
    import shlex
    return shlex.split(command, comments=True)


def _option_strings(parser):
    return {s for a in parser._actions for s in a.option_strings}


def _sub_parsers():
    return dict(_parsers())


def _parse(parser, argv):
    """argparse's complaint about ``argv`` (one line), or None if it parses."""
    import contextlib
    import io
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            parser.parse_args(argv)
    except SystemExit as exc:
        return None if exc.code == 0 else err.getvalue().strip() or f'exit {exc.code}'
    return None


def _bench_parser():
    from bench.__main__ import parser
    return parser()


def _check_tensegrity(args, loose, problems):
    """The sub-command and every option shown exist; without placeholders the whole command
    line parses as argparse would (nothing runs)."""
    from tensegrity_ros.cli import build_parser
    subs = _sub_parsers()
    if not args or PLACEHOLDER.search(args[0]):
        return
    sub = args[0]
    if sub not in subs and sub not in ('--help', '-h'):
        problems.append(f'unknown sub-command {sub!r}')
        return
    if sub == 'bench':
        parser, argv, options = _bench_parser(), args[1:], _option_strings(_bench_parser())
    else:
        parser, argv = build_parser(), args
        options = _option_strings(subs.get(sub, parser))
    for token in argv[1:] if sub != 'bench' else argv:
        if token == '--ros-args':
            break
        if token.startswith('-') and not re.match(r'-\d', token):
            name = token.split('=')[0].strip('[]')
            if name not in options:
                problems.append(f'{sub}: unknown option {name}')
    if not loose:
        complaint = _parse(parser, argv)
        if complaint:
            problems.append(f'{" ".join(args)}: {complaint}')


def _ros_args(args, problems, outputs):
    """``-p NAME:=VALUE`` names a parameter of the node; ``--params-file`` an existing file."""
    from tensegrity_ros.node.params import DEFAULTS, ROS_NAMES
    if '--ros-args' not in args:
        return
    rest = args[args.index('--ros-args') + 1:]
    for flag, value in zip(rest, rest[1:]):
        if flag == '-p' and ':=' in value:
            name, v = value.split(':=', 1)
            if name not in DEFAULTS and name not in ROS_NAMES:
                problems.append(f'unknown node parameter {name}')
            if name in ('record_mcap', 'record_rerun') and v:
                outputs.add(v)
        elif flag == '--params-file' and not (ROOT / value).exists():
            problems.append(f'--params-file {value}: no such file')


def _outputs_of(program, args):
    """The files and directories a command writes (relative paths)."""
    out = set()
    for opt, value in zip(args, args[1:]):
        if opt in OUTPUT_OPTIONS or (opt == '--rerun' and args[:1] == ['lens']):
            out.add(value.rstrip('/'))
    if program == 'tensegrity' and args[:1] == ['run'] and '--out' in args:
        d = args[args.index('--out') + 1]
        out |= {f'{d}/summary.json'} | {f'{d}/{f}' for flag, fs in (
            ('--mcap', ('run', 'run/run_0.mcap')), ('--rerun', ('run.rrd',)),
            ('--plot', ('strain_wave.png',))) if flag in args for f in fs}
        out.discard(d)
    if (program, args[:1]) in (('make', ['demo']), ('tensegrity', ['demo'])):
        out.add('runs/demo_focus' if '--focus' in args else 'runs/demo')
    return out


def _is_output(path, outputs):
    path = path.rstrip('/')
    return any(path == o or path.startswith(o + '/') for o in outputs)


def _input_paths(program, args):
    """The tokens of ``args`` that name files the command reads (outputs excluded)."""
    skip = False
    for i, token in enumerate(args):
        if skip:
            skip = False
            continue
        if token in OUTPUT_OPTIONS or (token == '--rerun' and args[:1] == ['lens']):
            skip = True
            continue
        if token == '--ros-args':
            return
        value = token.split('=', 1)[1] if token.startswith('-') and '=' in token else token
        if program == 'pip' or '://' in value or ':=' in value or PLACEHOLDER.search(value):
            continue
        if PATHLIKE.match(value) and not value.startswith(('-', '/tmp')):
            yield value


def check_commands(text, makefile=None):
    """Everything wrong with the commands of a page: programs run before ``.venv`` is activated,
    unknown sub-commands and options, command lines argparse refuses, unknown node parameters,
    files read that neither exist nor are written by an earlier command of the page, unknown
    make targets and Python modules."""
    makefile = (ROOT / 'Makefile').read_text() if makefile is None else makefile
    targets = set(re.findall(r'^([\w-]+):', makefile, flags=re.M))
    activated = next((n for n, line in enumerate(text.splitlines(), 1) if ACTIVATE in line), None)
    problems, outputs = [], set()
    for n, command, _ in _commands(text):
        tokens = _tokens(command)
        if not tokens:
            continue
        program, args = tokens[0], tokens[1:]
        where = f'line {n}: {command[:60]}'
        found = []
        if program.startswith('.venv/bin/'):
            found.append(f'{program}: the docs show the activated form ({program[10:]})')
        if program in VENV_PROGRAMS and (activated is None or activated > n):
            found.append(f'{program} before `{ACTIVATE}`')
        loose = any(PLACEHOLDER.search(t) for t in args)
        if program == 'tensegrity':
            _check_tensegrity(args, loose, found)
            if args[:1] == ['node']:
                _ros_args(args, found, outputs)
        elif program == 'tensegrity_node':
            _ros_args(args, found, outputs)
        elif program == 'make':
            found += [f'no make target {t}' for t in args if not t.startswith('-')
                      and '=' not in t and t not in targets]
        elif program == 'python' and args[:1] == ['-m']:
            module = args[1]
            if module == 'pytest':
                pass                                       # its files: the path check below
            else:
                base = ROOT / module.replace('.', '/')
                source = base.with_suffix('.py') if base.with_suffix('.py').exists() \
                    else base / '__main__.py'
                if not source.exists():
                    found.append(f'no module {module}')
                elif module == 'bench':
                    _check_tensegrity(['bench', *args[2:]], loose, found)
                else:
                    text_ = source.read_text()
                    found += [f'{module}: no option {t}' for t in args[2:]
                              if t.startswith('--') and f"'{t.split('=')[0]}'" not in text_]
        for path in _input_paths(program, args):
            if not (ROOT / path).exists() and not _is_output(path, outputs):
                found.append(f'reads {path}, which neither exists nor an earlier command writes')
        outputs |= _outputs_of(program, args)
        problems += [f'{where}: {p}' for p in found]
    for n, span in _inline_commands(text):
        found = []
        _check_tensegrity(_tokens(span)[1:], True, found)
        problems += [f'line {n}: `{span}`: {p}' for p in found]
    return problems


@pytest.mark.parametrize('page', PAGES, ids=lambda p: p.name)
def test_commands_shown_are_accepted(page):
    """Every command in the README and docs/ runs from a fresh shell as shown: ``.venv`` activated
    first, sub-commands, options and node parameters that exist, files that exist or that an
    earlier command writes."""
    problems = check_commands(_text(page))
    assert not problems, f'{page.name}:\n' + '\n'.join(problems)


def test_the_command_check_catches_what_a_user_would_hit():
    page = '\n'.join([
        '    tensegrity run config/scenes/fb_column.yaml',             # before activation
        '',
        '    . .venv/bin/activate',
        '    tensegrity fit config/scenes/fb_column.yaml --target target.yaml --free p=0:1',
        '    tensegrity run config/scenes/fb_column.yaml --v0 abc',
        '    tensegrity run config/scenes/fb_column.yaml --speed 1',
        '    tensegrity replay runs/x/run',
        '    tensegrity run config/scenes/fb_column.yaml --mcap --out runs/x',
        '    tensegrity replay runs/x/run --to-rerun runs/x/replay.rrd',   # fine
        '    rerun runs/x/run.rrd',                                # --rerun was not given
        '    tensegrity_node --ros-args -p publish_rate:=50',
        '    make install demo fly',
        '    python -m bench.node_overhead --no-such-flag',
        '    .venv/bin/tensegrity paper',
        '    tensegrity sweep SCENE.yaml --grid KEY=V1,V2 --resume',   # placeholders: options only
        '',
        'Inline too: `tensegrity paper --fast` and `tensegrity sweep SCENE.yaml --grid K=1,2`.',
    ])
    problems = '\n'.join(check_commands(page))
    for needle in ('line 1: tensegrity run config/scenes/fb_column.yaml: tensegrity before',
                   'reads target.yaml', "invalid float value: 'abc'", 'unknown option --speed',
                   'line 7: tensegrity replay runs/x/run: reads runs/x/run,',
                   'reads runs/x/run.rrd', 'unknown node parameter publish_rate',
                   'no make target fly', 'bench.node_overhead: no option --no-such-flag',
                   'sweep: unknown option --resume',
                   'the docs show the activated form (tensegrity)',
                   '`tensegrity paper --fast`: paper: unknown option --fast'):
        assert needle in problems, needle
    assert 'line 9' not in problems and 'no make target install' not in problems, problems


def test_shown_output_is_what_the_command_prints():
    """The README's example of a user error: the command run, its one line as shown."""
    import subprocess
    import sys
    shown = [(c, o) for _, c, o in _commands(_text(ROOT / 'README.md')) if o]
    assert shown
    for command, output in shown:
        args = _tokens(command)
        assert args[0] == 'tensegrity'
        res = subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', *args[1:]], cwd=ROOT,
                             capture_output=True, text=True, timeout=120)
        assert (res.stdout + res.stderr).strip().splitlines() == output, res.stderr


def test_programs_shown_are_installed_in_the_venv():
    """``tensegrity``, ``tensegrity_node`` and ``rerun`` are what activating ``.venv`` puts on the
    PATH (console scripts of setup.py; Rerun's viewer from rerun-sdk)."""
    import sys
    if sys.prefix == sys.base_prefix:
        pytest.skip('not running in a virtual environment')
    bindir = Path(sys.executable).parent
    missing = [p for p in ('tensegrity', 'tensegrity_node', 'rerun', 'pip')
               if not (bindir / p).exists()]
    assert not missing, f'not in {bindir}: {missing}'


