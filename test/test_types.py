"""
mypy on the annotated public API: the foundation, kinematics, robot model, control contract,
simulation configuration, task, DMP, segmentation and resampling.

The settings are the ``[mypy]`` sections of ``setup.cfg`` (every function annotated, no
implicit ``Optional``; PyBullet and the other untyped libraries are taken as ``Any``). A second
test shows that a call against an annotated signature is caught, so the first cannot pass by
checking nothing.
"""

import subprocess
import sys
import textwrap

from harness import REPO

# The modules whose public API is annotated, checked with every function typed.
ANNOTATED = ('sim_bridge/common',
             'sim_bridge/kinematics',
             'sim_bridge/robot_model.py',
             'sim_bridge/control.py',
             'sim_bridge/simulation_config.py',
             'sim_bridge/task.py',
             'sim_bridge/observers.py',
             'sim_bridge/kinematic_errors.py',
             'sim_bridge/scene',
             'sim_bridge/trajectory.py',
             'sim_bridge/physics.py',
             'sim_bridge/simulation.py',
             'sim_bridge/arm.py',
             'suture_lfd/dmp',
             'suture_lfd/segmentation',
             'suture_lfd/assessment',
             'suture_lfd/bags',
             'suture_lfd/planning',
             'suture_lfd/demos/resampling.py',
             'suture_lfd/demos/demonstration.py',
             'suture_lfd/demos/synthetic_throw.py',
             'suture_lfd/demos/segment_file.py',
             'suture_lfd/demos/cohort.py',
             'suture_lfd/demos/scripted_demo.py',
             'suture_lfd/skill/method.py',
             'suture_lfd/study/digest.py',
             'suture_lfd/study/options.py',
             'suture_lfd/study/keys.py',
             'suture_lfd/study/figures.py',
             'suture_lfd/perception/arc_poses.py',
             'suture_lfd/demos/demo_bag.py',
             'suture_lfd/demos/demonstrator.py',
             'suture_lfd/study/records.py',
             'suture_lfd/study/physical.py',
             'suture_lfd/study/store.py',
             'suture_lfd/study/runner.py',
             'suture_lfd/study/pool.py',
             'suture_lfd/study/signals.py',
             'suture_lfd/study/engine.py',
             'suture_lfd/study/tables.py',
             'suture_lfd/study/metrics.py',
             'suture_lfd/study/jobs.py',
             'suture_lfd/study/held_out.py',
             'suture_lfd/study/assessed.py',
             'suture_lfd/study/report.py',
             'suture_lfd/study/run.py',
             'suture_lfd/study/sweep.py',
             'suture_lfd/study/stages.py',
             'suture_lfd/study/ros.py',
             'suture_lfd/study/teleoperated.py',
             'suture_lfd/viewer/assets.py',
             'suture_lfd/viewer/show.py',
             'suture_lfd/viewer/filmstrip.py',
             'suture_lfd/viewer/throw_replay.py',
             'suture_lfd/viewer/perceived.py',
             'suture_lfd/viewer/replay.py',
             'suture_lfd/viewer/scene.py',
             'suture_lfd/skill/executor_machine.py',
             'suture_lfd/skill/registration_run.py',
             'suture_lfd/skill/perceived_feed.py',
             'suture_lfd/viewer/controls.py',
             'suture_lfd/viewer/stereo.py',
             'suture_lfd/skill/training.py',
             'suture_lfd/skill/watchdog.py',
             'suture_lfd/skill/perceived.py',
             'suture_lfd/errors.py',
             'sim_bridge/bullet.py',
             'suture_lfd/skill/throw_skill.py',
             'suture_lfd/skill/executor.py',
             'suture_lfd/perception/instrument.py',
             'suture_lfd/teleop',
             'suture_lfd/cli.py',
             'suture_lfd/viewer/page.py',
             'suture_lfd/skill/physical_demo.py',
             'suture_lfd/skill/arm_registration.py',
             *(f'suture_lfd/perception/{name}.py' for name in (
                 '__init__', 'arc_stereo', 'evaluation', 'grasp', 'images', 'markers', 'needle',
                 'pipeline', 'reacquire', 'stereo', 'wire_images')))


def run_mypy(paths, cache_dir):
    """Run mypy with the repository's settings; return (exit code, output)."""
    result = subprocess.run(
        [sys.executable, '-m', 'mypy', '--config-file', str(REPO / 'setup.cfg'),
         '--cache-dir', str(cache_dir), '--no-error-summary', *map(str, paths)],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    return result.returncode, result.stdout + result.stderr


def test_annotated_modules_type_check(tmp_path):
    code, output = run_mypy([REPO / path for path in ANNOTATED], tmp_path / 'cache')
    assert code == 0, f'mypy found errors in the annotated public API:\n{output}'


def test_a_call_against_an_annotated_signature_is_reported(tmp_path):
    caller = tmp_path / 'caller.py'
    caller.write_text(textwrap.dedent("""
        from sim_bridge.common.geometry import invert_transform
        from suture_lfd.dmp import load_dmp_params

        angle: float = invert_transform([[1.0]])
        params = load_dmp_params(task=2)
    """))
    code, output = run_mypy([caller], tmp_path / 'cache')
    assert code == 1, output
    assert 'caller.py:5: error: Incompatible types in assignment' in output, output
    assert 'caller.py:6: error: Argument "task" to "load_dmp_params"' in output, output
