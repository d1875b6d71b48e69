import subprocess
import sys

CORE = ('geometry', 'validation', 'dmp', 'dmp_base', 'dmp_equations', 'position_dmp',
        'quaternion_dmp', 'resampling', 'segmentation', 'suturing_frames', 'metrics',
        'demonstration', 'synthetic_throw')


def test_lfd_core_modules_never_import_ros():
    code = ('import importlib, sys\n'
            f'for name in {CORE!r}:\n'
            "    importlib.import_module('suture_lfd.' + name)\n"
            "bad = sorted(m for m in sys.modules if m == 'rclpy' or m.startswith('rclpy.')"
            " or m.split('.')[0].endswith('_msgs'))\n"
            'print(bad)\n'
            'sys.exit(1 if bad else 0)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
