"""The node entry point's argument handling and help, without starting ROS."""

from sim_bridge.common.configfile import load_yaml
from sim_bridge.common.paths import config_path
from sim_bridge.ros.entry import help_text, parameter_overrides, split_arguments


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
