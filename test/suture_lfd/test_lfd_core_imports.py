import subprocess
import sys

CORE = ('sim_bridge.common.geometry', 'sim_bridge.common.validation', 'suture_lfd.dmp',
        'suture_lfd.dmp.base',
        'suture_lfd.dmp.equations', 'suture_lfd.dmp.position', 'suture_lfd.dmp.quaternion',
        'suture_lfd.demos.resampling', 'suture_lfd.segmentation',
        'suture_lfd.planning.suturing_frames', 'suture_lfd.study.metrics',
        'suture_lfd.demos.demonstration', 'suture_lfd.demos.synthetic_throw')


def test_lfd_core_modules_never_import_ros():
    code = ('import importlib, sys\n'
            f'for name in {CORE!r}:\n'
            "    importlib.import_module(name)\n"
            "bad = sorted(m for m in sys.modules if m == 'rclpy' or m.startswith('rclpy.')"
            " or m.split('.')[0].endswith('_msgs'))\n"
            'print(bad)\n'
            'sys.exit(1 if bad else 0)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
