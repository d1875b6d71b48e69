"""
Sphinx extension: the manual's reference pages, generated from the code's own declarations.

At ``builder-inited`` it writes Markdown pages under ``doc/reference/generated/`` (not kept in
git), so nothing in them is typed twice:

- ``nodes/<executable>.md``: every node executable of ``setup.py`` (the
  :class:`sim_bridge.ros.entry.Executable` objects of ``sim_bridge.nodes.executables`` and
  ``suture_lfd.nodes.executables``): the node module's docstring (its topics, services and
  behaviour) and its parameters, one per field of the configuration dataclass the node passes to
  :func:`sim_bridge.ros.params.declare_config`, with the default and comment of
  ``config/<node>.yaml``;
- ``cli.md``: every sub-command and option of ``suture-lfd`` from its argparse parsers
  (:func:`suture_lfd.cli.build_parser`);
- ``config.md``: every key of every ``config/*.yaml`` file with its value and comment.

The Python API (``reference/api.rst``) is autosummary's, from the docstrings.
"""

import argparse
import ast
import dataclasses
import importlib
import inspect
from pathlib import Path
import re
import types
import typing

DOC = Path(__file__).resolve().parents[1]
REPO = DOC.parent
OUT = DOC / 'reference' / 'generated'
EXECUTABLE_MODULES = ('sim_bridge.nodes.executables', 'suture_lfd.nodes.executables')


def _write(path, text):
    """Write ``text`` to ``path`` unless it holds it already (keeps Sphinx's cache valid)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def _cell(text):
    """Text made safe for one cell of a Markdown table."""
    return str(text).replace('|', '\\|').replace('\n', ' ')


def executables():
    """
    Return the node executables of the package, by name.

    Returns
    -------
    dict of str to sim_bridge.ros.entry.Executable

    """
    from sim_bridge.ros.entry import Executable

    found = {}
    for name in EXECUTABLE_MODULES:
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, Executable):
                found[value.name] = value
    return dict(sorted(found.items()))


def node_config_class(executable):
    """
    Return the configuration dataclass a node declares its parameters from, or None.

    The node module's call ``declare_config(self, <Class>, '<file>.yaml', ...)`` names it.

    Parameters
    ----------
    executable : sim_bridge.ros.entry.Executable
        The node's executable.

    Returns
    -------
    type or None

    """
    module = importlib.import_module(executable.target.partition(':')[0])
    tree = ast.parse(inspect.getsource(module))
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'declare_config'
                and len(node.args) >= 2 and isinstance(node.args[1], ast.Name)):
            return getattr(module, node.args[1].id)
    return None


def node_parameters(executable):
    """
    Return a node's declared parameters: name, type, default and comment.

    Parameters
    ----------
    executable : sim_bridge.ros.entry.Executable
        The node's executable.

    Returns
    -------
    list of tuple of (str, str, object, str)

    """
    from sim_bridge.common.configfile import load_yaml
    from sim_bridge.common.paths import config_path
    from sim_bridge.ros.entry import _section_comments  # the --help's own reading

    cls = node_config_class(executable)
    if cls is None:
        return []
    path = config_path(executable.config_file)
    data = load_yaml(path)
    params = (data.get(executable.name) or {}).get('ros__parameters') or {}
    comments = _section_comments(path.read_text().splitlines(), executable.name)
    hints = typing.get_type_hints(cls)
    rows = []
    for field in dataclasses.fields(cls):
        if field.name in params:
            default = params[field.name]
        elif field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            default = '(required)'
        kind = getattr(hints[field.name], '__name__', str(hints[field.name]))
        rows.append((field.name, kind, default, comments.get(field.name, '')))
    return rows


def _format_default(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if value == '':
        return "''"
    return str(value)


def node_page(executable):
    """Return the Markdown reference page of one node executable."""
    module = executable.target.partition(':')[0]
    lines = [f'# `{executable.name}`', '',
             f'Run it as `./suture-lfd {executable.name}` or `ros2 run suture_lfd '
             f'{executable.name}`; `--help` prints its parameters without starting ROS.', '']
    if executable.example:
        lines += ['Example:', '', '```bash', executable.example, '```', '']
    lines += ['## Topics, services and behaviour', '',
              f'From the node module {{py:mod}}`{module}`:', '',
              '```{eval-rst}', f'.. automodule:: {module}', '   :no-members:',
              '   :no-index:', '```', '']
    rows = node_parameters(executable)
    lines += ['## Parameters', '']
    if rows:
        lines += [f'Declared from `config/{executable.config_file}` (section '
                  f'`{executable.name}: ros__parameters:`); set one with '
                  '`--ros-args -p NAME:=VALUE`.', '',
                  '| parameter | type | default | meaning |', '|---|---|---|---|']
        for name, kind, default, comment in rows:
            lines.append(f'| `{name}` | {kind} | `{_cell(_format_default(default))}` | '
                         f'{_cell(comment)} |')
    else:
        lines.append('None.')
    return '\n'.join(lines) + '\n'


def _parser_section(parser, title, level):
    lines = [f'{"#" * level} `{title}`', '', '```text', parser.format_usage().strip(), '```', '']
    if parser.description:
        lines += [parser.description, '']
    rows = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction | argparse._HelpAction):
            continue
        name = ', '.join(action.option_strings) or action.dest
        default = '' if action.default in (None, argparse.SUPPRESS) or not action.option_strings \
            else f'`{_cell(action.default)}`'
        rows.append(f'| `{_cell(name)}` | {default} | {_cell(action.help or "")} |')
    if rows:
        lines += ['| argument | default | meaning |', '|---|---|---|', *rows, '']
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                lines += _parser_section(sub, f'{title} {name}', min(level + 1, 4))
    return lines


def cli_page():
    """Return the Markdown reference page of the ``suture-lfd`` command line."""
    from suture_lfd.cli import build_parser

    parser = build_parser()
    lines = ['# Command line', '',
             'Every sub-command of `./suture-lfd` (the same as `.venv/bin/suture-lfd` once set '
             'up), with every option, read from its argparse parsers. `./suture-lfd test`, '
             '`./suture-lfd setup` and `./suture-lfd docs` are commands of the wrapper script '
             "itself; `./suture-lfd NAME` runs the node executable NAME (see the nodes' "
             'pages).', '']
    lines += _parser_section(parser, 'suture-lfd', 2)
    return '\n'.join(lines) + '\n'


_KEY = re.compile(r'^(\s*)([A-Za-z_][\w.\-]*|"[^"]+"|\'[^\']+\'):(?:\s+(.*?))?\s*$')


def _split_comment(text):
    """Split a YAML value from its trailing comment (a ``#`` after a space, outside quotes)."""
    quote = None
    for i, ch in enumerate(text):
        if ch in '\'"':
            quote = None if quote == ch else (quote or ch)
        elif ch == '#' and quote is None and (i == 0 or text[i - 1] in ' \t'):
            return text[:i].rstrip(), text[i + 1:].strip()
    return text.rstrip(), ''


def config_keys(path):
    """
    Return the keys of a YAML file with their value text and comment.

    Parameters
    ----------
    path : pathlib.Path
        The file.

    Returns
    -------
    header : str
        The file's leading comment.
    keys : list of tuple of (str, str, str)
        Dotted key, value as written (empty for a mapping) and its comment (the lines just
        above it and its trailing comment).

    """
    header, keys, stack, above, started = [], [], [], [], False
    for line in path.read_text().splitlines():
        stripped = line.strip()
        if not stripped:
            above = []
            continue
        if stripped.startswith('#'):
            (above if started else header).append(stripped.lstrip('#').strip())
            continue
        started = True
        match = _KEY.match(line)
        if not match:
            above = []
            continue
        indent = len(match.group(1))
        while stack and stack[-1][0] >= indent:
            stack.pop()
        key = match.group(2).strip('\'"')
        value, comment = _split_comment(match.group(3) or '')
        stack.append((indent, key))
        dotted = '.'.join(k for _, k in stack)
        keys.append((dotted, value, ' '.join([*above, comment]).strip()))
        above = []
    return ' '.join(header), keys


def config_page():
    """Return the Markdown reference page of the configuration files in ``config/``."""
    lines = ['# Configuration files', '',
             'Every key of every file in `config/`, as installed with the package, with its '
             'value and the comment beside it. Node files have the shape '
             '`<node>: ros__parameters: {...}`; the node pages list their parameters with types.',
             '']
    for path in sorted((REPO / 'config').glob('*.yaml')):
        header, keys = config_keys(path)
        lines += [f'## `{path.name}`', '']
        if header:
            lines += [header, '']
        if keys:
            lines += ['| key | value | comment |', '|---|---|---|']
            lines += [f'| `{_cell(k)}` | {"`" + _cell(v) + "`" if v else ""} | {_cell(c)} |'
                      for k, v, c in keys]
            lines.append('')
    return '\n'.join(lines) + '\n'


def generate(app):
    """Write the generated reference pages (``builder-inited``)."""
    nodes = executables()
    for name, executable in nodes.items():
        _write(OUT / 'nodes' / f'{name}.md', node_page(executable))
    index = ['# Nodes', '',
             'One page per node executable: its topics, services and behaviour, and its '
             'parameters with their defaults.', '', '```{toctree}', ':maxdepth: 1', '',
             *nodes, '```', '']
    _write(OUT / 'nodes' / 'index.md', '\n'.join(index))
    _write(OUT / 'cli.md', cli_page())
    _write(OUT / 'config.md', config_page())


def skip_type_alias(app, what, name, obj, skip, options):
    """
    Leave type aliases out of the API pages.

    Autodoc takes an alias such as ``FloatArray = NDArray[np.float64]`` for a function and
    cannot give it a signature; its comment stays in the module's source.
    """
    if isinstance(obj, types.GenericAlias) or type(obj).__module__ == 'typing':
        return True
    return None


def setup(app):
    """Register the generator with Sphinx."""
    app.connect('builder-inited', generate, priority=100)  # before autosummary
    app.connect('autodoc-skip-member', skip_type_alias)
    return {'parallel_read_safe': True, 'parallel_write_safe': True}
