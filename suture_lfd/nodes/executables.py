"""
The executables of the pipeline (``setup.py`` console scripts): name, node, help example.

Each is a :class:`sim_bridge.ros.entry.Executable`: ``--help`` is answered before the node's
module is imported or ROS is initialised.
"""

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
