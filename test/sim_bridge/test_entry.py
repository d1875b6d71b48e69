"""The node entry point's argument handling and help, without starting ROS."""

import ast
import textwrap

from harness import REPO
from sim_bridge.common.configfile import load_yaml
from sim_bridge.common.paths import config_path
from sim_bridge.ros.entry import NodeHooks, help_text, parameter_overrides, split_arguments


def test_ros_arguments_are_told_from_the_users():
    user, ros = split_arguments(['--ros-args', '-p', 'pair:=synth2', '-r', '__ns:=/a', '--',
                                 '--pair', 'synth3', '--ros-args', '-p', 'seed:=1'])
    assert user == ['--pair', 'synth3']
    assert ros == ['-p', 'pair:=synth2', '-r', '__ns:=/a', '-p', 'seed:=1']
    assert split_arguments([]) == ([], [])


def test_parameter_overrides_name_the_node_they_are_for():
    ros = ['-p', 'subject:=S02', '--param', 'demonstrator:seed:=3', '-r', 'a:=b',
           '--params-file', 'x.yaml']
    assert parameter_overrides(ros) == [(None, 'subject'), ('demonstrator', 'seed')]


def test_help_lists_every_parameter_with_its_default_and_comment():
    text = help_text('executor', 'Executor node: learns a throw.\n\nMore.', 'executor.yaml',
                     'executor --ros-args -p pair:=synth3')
    params = load_yaml(config_path('executor.yaml'))['executor']['ros__parameters']
    lines = text.splitlines()
    assert lines[0].startswith('usage: executor') and 'Executor node: learns a throw.' in text
    assert 'More.' not in text
    for name, value in params.items():
        line = next(x for x in lines if x.startswith(f'  {name} '))
        shown = (str(value).lower() if isinstance(value, bool) else "''" if value == ''
                 else str(value))
        assert f'= {shown}' in line, (name, line)
    assert 'segment file to learn from' in text
    assert max(len(x) for x in lines) <= 99
    assert text.rstrip().endswith('executor --ros-args -p pair:=synth3')


# --- the hooks run_node calls are declared -------------------------------------------------------

HOOKS = {'companions', 'finished', 'exit_code', 'run', 'on_start', 'on_interrupt', 'on_exit'}


def undeclared_hooks(paths):
    """Return each ``Node`` class that defines or sets a hook without listing ``NodeHooks``."""
    found = []
    for path in paths:
        for cls in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not isinstance(cls, ast.ClassDef):
                continue
            bases = {ast.unparse(base).rpartition('.')[2] for base in cls.bases}
            defined = {node.name for node in cls.body if isinstance(node, ast.FunctionDef)}
            assigned = {target.attr for node in ast.walk(cls) if isinstance(node, ast.Assign)
                        for target in node.targets if isinstance(target, ast.Attribute)
                        and isinstance(target.value, ast.Name) and target.value.id == 'self'}
            hooks = sorted((defined | assigned) & HOOKS)
            if hooks and 'Node' in bases and 'NodeHooks' not in bases:
                found.append(f'{path.name}: {cls.name} has {", ".join(hooks)} but does not list '
                             'NodeHooks among its bases')
    return found


def node_modules(root):
    """The node modules of both packages."""
    return sorted([*(root / 'sim_bridge/nodes').glob('*.py'),
                   *(root / 'suture_lfd/nodes').glob('*.py')])


def test_every_node_with_a_hook_declares_node_hooks():
    assert len(node_modules(REPO)) > 5
    assert undeclared_hooks(node_modules(REPO)) == []


def test_a_node_with_an_undeclared_hook_is_named(tmp_path):
    (tmp_path / 'probe.py').write_text(textwrap.dedent("""
        class Quiet(Node):
            def on_exit(self):
                pass

        class Declared(NodeHooks, Node):
            def on_exit(self):
                pass

        class Ending(rclpy.node.Node):
            def __init__(self):
                self.finished = False
    """))
    assert undeclared_hooks([tmp_path / 'probe.py']) == [
        'probe.py: Quiet has on_exit but does not list NodeHooks among its bases',
        'probe.py: Ending has finished but does not list NodeHooks among its bases']


def test_a_node_without_hooks_runs_with_the_defaults():
    hooks = NodeHooks()
    assert (hooks.run(), hooks.finished, hooks.exit_code, tuple(hooks.companions)) == \
        (None, False, 0, ())
