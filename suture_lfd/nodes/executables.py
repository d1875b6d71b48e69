"""
The executables of the pipeline (``setup.py`` console scripts): name, node, help example.

Each is a :class:`sim_bridge.ros.entry.Executable`: ``--help`` is answered before the node's
module is imported or ROS is initialised.
"""

import sys

from sim_bridge.ros.entry import Executable

demonstrator = Executable(
    'demonstrator', 'suture_lfd.nodes.demonstrator:DemonstratorNode',
    config_file='demonstrator.yaml',
    example='demonstrator --ros-args -p subject:=S03 -p pair:=synth2 -p seed:=1')
recorder = Executable(
    'recorder', 'suture_lfd.nodes.recorder:Recorder', config_file='recorder.yaml',
    example='recorder --ros-args -p output_dir:=demonstrations -p prefix:=demo')
player = Executable(
    'player', 'suture_lfd.nodes.player:Player', config_file='player.yaml',
    example='player --ros-args -p bag:=demonstrations/demo_20260101-120000_1 -p rate:=2.0')
segmenter = Executable(
    'segmenter', 'suture_lfd.nodes.segmenter:Segmenter', config_file='segmenter.yaml',
    example='segmenter --ros-args -p bag:=demonstrations/demo_20260101-120000_1')
executor = Executable(
    'executor', 'suture_lfd.nodes.executor:ExecutorNode', config_file='executor.yaml',
    example='executor --ros-args -p segments:=demo.segments.npz -p pair:=synth3 '
            '-p result_file:=result.json')
teleop = Executable(
    'teleop', 'suture_lfd.nodes.teleop:TeleopNode', config_file='teleop.yaml',
    example='teleop --ros-args -r __node:=MTMR_PSM1 -p mtm:=MTMR -p psm:=PSM1')
mtms = Executable(
    'mtms', 'suture_lfd.nodes.mtms:MtmsNode', config_file='mtms.yaml',
    example='mtms --ros-args -p device:=browser')
perception = Executable(
    'perception', 'suture_lfd.nodes.perception:PerceptionNode', config_file='perception.yaml',
    example='perception --ros-args -p rate:=5.0')
_viewer = Executable(
    'viewer', 'suture_lfd.nodes.viewer:Viewer', config_file='viewer.yaml',
    example='viewer --host 127.0.0.1 --port 8080 --ros-args -p phantom:=scanned')


def _listen_arguments(argv):
    """
    Turn ``--host ADDRESS`` and ``--port N`` into the ``host`` and ``port`` parameters.

    Parameters
    ----------
    argv : list of str
        Command-line arguments without the program name.

    Returns
    -------
    list of str
        ``argv`` without them, ``--ros-args -p host:=ADDRESS -p port:=N`` appended.

    """
    if '--ros-args' in argv:
        k = argv.index('--ros-args')
        user, ros = list(argv[:k]), list(argv[k:])
    else:
        user, ros = list(argv), []
    out, params = [], []
    i = 0
    while i < len(user):
        arg = user[i]
        name, eq, value = arg.partition('=')
        if name in ('--host', '--port'):
            if not eq:
                if i + 1 >= len(user):
                    raise ValueError(f'{name} needs a value')
                value = user[i + 1]
                i += 1
            params += ['-p', f'{name[2:]}:={value}']
        else:
            out.append(arg)
        i += 1
    if params:
        ros += ['--ros-args', *params]
    return out + ros


def viewer(args=None):
    """Run the viewer node; ``--host ADDRESS`` and ``--port N`` set where its page listens."""
    argv = list(sys.argv[1:] if args is None else args)
    if any(a in ('-h', '--help') for a in argv):
        return _viewer(argv)
    try:
        argv = _listen_arguments(argv)
    except ValueError as exc:
        print(f'viewer: error: {exc}', file=sys.stderr, flush=True)
        return 2
    return _viewer(argv)
