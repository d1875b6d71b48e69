"""
Segmenter node: a demonstration bag in, a segment file for the executor out.

Reads the bag named by the ``bag`` parameter
(:func:`suture_lfd.demos.demo_bag.demonstration_from_bag`: tool, jaw, needle, marker and event
topics of the simulator; a bag recorded in physical mode, without those, through
:func:`suture_lfd.skill.physical_demo.demonstration_from_physical_bag`: the arms' reports and
the perception node's needle and markers), cuts it into the five subtasks
(:func:`suture_lfd.segmentation.segment_demonstration`), resamples the needle trajectories of tasks
ii and iv and writes the :class:`suture_lfd.demos.segment_file.SegmentFile` to ``output``
(default ``<bag>.segments.npz`` beside the bag). Publishes a JSON summary on ``~/result`` (latched)
and exits: code 0 when the file was written, 1 when the bag could not be segmented (the error names
the bag and what is missing). Parameters: ``config/segmenter.yaml``.
"""

from dataclasses import dataclass
import json
from pathlib import Path
import sys

from rclpy.node import Node
from sim_bridge.ros import qos
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from std_msgs.msg import String
from suture_lfd import bags
from suture_lfd.demos.demo_bag import demonstration_from_bag
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.nodes import executables
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill.physical_demo import demonstration_from_physical_bag, is_physical_bag


@dataclass(frozen=True)
class SegmenterConfig:
    """Parameters of the segmenter node (names as in ``config/segmenter.yaml``)."""

    bag: str = ''
    output: str = ''
    pair: str = ''
    subject: str = ''
    sample_rate: float = 100.0
    dmp_config: str = ''

    def __post_init__(self):
        if not self.sample_rate > 0:
            raise ValueError(f'parameter sample_rate must be > 0 Hz, got {self.sample_rate}')


def default_output(bag):
    """Return the default segment file of a bag: ``<bag>.segments.npz`` beside it."""
    bag = Path(bag)
    return bag.with_name(bag.name + '.segments.npz')


def segment_bag(config):
    """
    Segment the configured bag and write its segment file.

    Parameters
    ----------
    config : SegmenterConfig
        Bag, output and options.

    Returns
    -------
    dict
        Summary: bag, output, pair, subtask times (s) and durations.

    """
    if not config.bag:
        raise ValueError('parameter bag is empty: name the demonstration bag to segment')
    if is_physical_bag(bags.bag_summary(config.bag).topics):
        # recorded on what a dVRK provides: the needle as perceived
        demo = demonstration_from_physical_bag(config.bag, pair=config.pair or None,
                                               sample_rate=config.sample_rate)
    else:
        demo = demonstration_from_bag(config.bag, pair=config.pair or None,
                                      sample_rate=config.sample_rate)
    try:
        segmentation = segment_demonstration(demo)
    except ValueError as exc:
        raise ValueError(f'{config.bag}: cannot segment the demonstration: {exc}') from exc
    segments = make_segment_file(demo, segmentation, dmp_config=config.dmp_config or None,
                                 source=str(config.bag), subject=config.subject)
    output = Path(config.output) if config.output else default_output(config.bag)
    output.parent.mkdir(parents=True, exist_ok=True)
    segments.save(output)
    return {'bag': str(config.bag), 'output': str(output), 'pair': demo.pair,
            'duration': demo.duration,
            'subtasks': {name: list(segments.times(name)) for name in segments.durations},
            'durations': segments.durations}


class Segmenter(NodeHooks, Node):
    """Segment one bag into a segment file."""

    def __init__(self):
        super().__init__('segmenter')
        self.config = declare_config(self, SegmenterConfig, 'segmenter.yaml', 'segmenter')
        self._result = self.create_publisher(String, '~/result', qos.LATCHED)

    def run(self):
        """Segment the bag; return the exit code."""
        try:
            summary = segment_bag(self.config)
        except (ValueError, OSError) as exc:
            self.get_logger().error(str(exc))
            self._result.publish(String(data=json.dumps({'bag': self.config.bag,
                                                         'error': str(exc)})))
            return 1
        self.get_logger().info(
            f'{summary["bag"]}: five subtasks ('
            + ', '.join(f'{k} {v:.2f} s' for k, v in summary['durations'].items())
            + f') written to {summary["output"]}')
        self._result.publish(String(data=json.dumps(summary, sort_keys=True)))
        return 0


def main(args=None):
    return executables.segmenter(args)


if __name__ == '__main__':
    sys.exit(main())
