"""
The manual builds with warnings as errors, and its reference lists what the code declares.

One Sphinx build of ``doc/`` (as ``./suture-lfd docs`` runs it, into a temporary folder) serves
every test: a broken cross-reference, a docstring that does not parse or a page left out of
the tree fails the build. The pages are then read as a browser gets them (HTML, tags stripped)
and checked against the code itself: the API page of ``sim_bridge.simulation.Simulation``, the
``simulator`` node's parameters, every parameter of every node and every option of the
command line.
"""

import argparse
import dataclasses
import html
from pathlib import Path
import re
import subprocess
import sys

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope='module')
def manual(tmp_path_factory):
    """Build the manual once; return the folder of its HTML pages."""
    out = tmp_path_factory.mktemp('manual')
    result = subprocess.run(
        [sys.executable, '-m', 'sphinx', '-b', 'html', '-W', '--keep-going', '-q',
         '-d', str(out / 'doctrees'), str(REPO / 'doc'), str(out / 'html')],
        capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, f'the manual does not build cleanly:\n{result.stderr[-6000:]}'
    return out / 'html'


def page_text(path):
    """The text of an HTML page as a reader sees it (tags stripped, entities decoded)."""
    assert path.is_file(), f'page {path.name} was not built'
    raw = path.read_text()
    return raw, html.unescape(re.sub(r'<[^>]+>', ' ', raw))


def mentions(text, word):
    return re.search(r'(?<![\w-])' + re.escape(word) + r'(?![\w-])', text) is not None


def test_simulation_api_page_lists_its_public_methods(manual):
    from sim_bridge.simulation import Simulation

    raw, _ = page_text(manual / 'reference' / 'api' / 'sim_bridge.simulation.html')
    assert 'id="sim_bridge.simulation.Simulation"' in raw
    public = [name for name, value in vars(Simulation).items()
              if not name.startswith('_') and getattr(value, '__doc__', None)
              and (callable(value) or isinstance(value, property))]
    assert len(public) >= 5
    missing = [n for n in public if f'id="sim_bridge.simulation.Simulation.{n}"' not in raw]
    assert not missing, f'Simulation members missing from its API page: {missing}'


def test_simulator_node_page_lists_every_declared_parameter(manual):
    from sim_bridge.nodes.simulator import SimulatorConfig

    _, text = page_text(manual / 'reference' / 'generated' / 'nodes' / 'simulator.html')
    names = [f.name for f in dataclasses.fields(SimulatorConfig)]
    assert len(names) > 10
    missing = [n for n in names if not mentions(text, n)]
    assert not missing, f'simulator parameters missing from its reference page: {missing}'


def _node_parameter_files():
    """Each node executable's name and parameter file, read from the executables' modules."""
    import sim_bridge.nodes.executables as sim_exes
    from sim_bridge.ros.entry import Executable
    import suture_lfd.nodes.executables as lfd_exes

    return sorted((v.name, v.config_file) for m in (sim_exes, lfd_exes)
                  for v in vars(m).values() if isinstance(v, Executable))


def test_every_node_has_a_page_listing_its_parameters(manual):
    from sim_bridge.common.configfile import load_yaml

    nodes = _node_parameter_files()
    assert {'simulator', 'executor', 'recorder', 'perception'} <= {n for n, _ in nodes}
    for name, config_file in nodes:
        _, text = page_text(manual / 'reference' / 'generated' / 'nodes' / f'{name}.html')
        if config_file is None:
            continue
        params = (load_yaml(REPO / 'config' / config_file).get(name) or {}).get(
            'ros__parameters') or {}
        missing = [p for p in params if not mentions(text, p)]
        assert not missing, f'{name}: parameters missing from its reference page: {missing}'


def _options(parser, prefix=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield (*prefix, sub_name), None
                yield from _options(sub, (*prefix, sub_name))
        elif not isinstance(action, argparse._HelpAction):
            for option in action.option_strings or [action.dest]:
                yield prefix, option


def test_every_cli_option_is_in_the_reference(manual):
    from suture_lfd.cli import build_parser

    _, text = page_text(manual / 'reference' / 'generated' / 'cli.html')
    options = list(_options(build_parser()))
    assert any(o == '--physical' for _, o in options)
    missing = [(' '.join(c), o) for c, o in options
               if not mentions(text, o if o is not None else ' '.join(c))]
    assert not missing, f'command-line options missing from the reference: {missing}'


def test_the_readme_is_short_and_points_to_the_manual():
    readme = (REPO / 'README.md').read_text()
    assert len(readme.splitlines()) <= 150
    assert './suture-lfd docs' in readme
    for link in re.findall(r'\]\((doc/[^)#]+)', readme):
        assert (REPO / link).exists(), f'README links to {link}, which does not exist'
