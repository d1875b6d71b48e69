"""
The pipeline's executor node beside a simulator in physical mode, read from the ROS graph.

Real processes on loopback: with the ground truth published under ``/evaluation/``, the
executor node subscribes to none of it (its subscriptions, as the graph lists them); remapping
one of its inputs into ``/evaluation/`` is refused with a message naming the topic.
"""

import pytest
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration


@pytest.fixture(scope='module')
def segments(simulation, tmp_path_factory):
    demo, _, score = record_scripted_demonstration(simulation, 'synth1', seed=0)
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('physical_graph') / 'synth1_segments.npz'
    make_segment_file(demo, segment_demonstration(demo), source='scripted expert').save(path)
    return path


def test_with_the_truth_published_for_the_evaluation_the_executor_reads_none_of_it(
        launch, ros, segments):
    sim = launch('simulator', '--ros-args', '-p', 'real_time_factor:=0.25',
                 '-p', 'physical:=true', '-p', 'kinematic_error_level:=3.0')
    executor = launch('executor', '--ros-args', '-p', f'segments:={segments}')
    probe = ros.node('graph_probe')

    def subscriptions():
        try:
            return dict(probe.get_subscriber_names_and_types_by_node('executor', '/'))
        except Exception:  # noqa: BLE001 (the node is not in the graph yet)
            return {}

    def truth_published():
        return '/evaluation/sim/needle/measured_cp' in dict(probe.get_topic_names_and_types())

    assert ros.wait_for(lambda: truth_published() and '/PSM1/measured_cp' in subscriptions(),
                        120.0), (sim.log(), executor.log())
    subs = subscriptions()
    assert not [t for t in subs if t.startswith('/evaluation/')], sorted(subs)
    assert executor.running(), executor.log()


def test_an_input_remapped_into_the_evaluation_is_refused_with_its_name(launch, segments):
    proc = launch('executor', '--ros-args', '-p', f'segments:={segments}',
                  '-r', 'sim/needle/measured_cp:=/evaluation/sim/needle/measured_cp')
    assert proc.popen.wait(120) != 0
    log = proc.log()
    assert '/evaluation/sim/needle/measured_cp' in log and 'for the evaluation only' in log
