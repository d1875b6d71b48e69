"""The package as a user installs it: layering, messages over DDS, colcon, lint, setup errors."""

from importlib import metadata
import os
from pathlib import Path
import shutil
import subprocess
import sys
import textwrap

from harness import DOMAIN_ID, REPO, SIGINT_EXIT, wait_for
import pytest

ROS_FACES = ('nodes', 'ros')


def core_modules():
    mods = []
    for pkg in ('sim_bridge', 'suture_lfd'):
        for path in sorted((REPO / pkg).rglob('*.py')):
            rel = path.relative_to(REPO)
            if any(part in ROS_FACES for part in rel.parts):
                continue
            mods.append('.'.join(rel.with_suffix('').parts).removesuffix('.__init__'))
    return mods


def node_executables():
    dist = metadata.distribution('suture_lfd')
    return sorted(ep.name for ep in dist.entry_points
                  if ep.group == 'console_scripts' and ep.name != 'suture-lfd')


def test_core_modules_never_load_rclpy_or_messages():
    mods = core_modules()
    assert 'sim_bridge.common.configfile' in mods and 'suture_lfd.cli' in mods
    code = textwrap.dedent(f"""
        import importlib, sys
        for m in {mods!r}:
            importlib.import_module(m)
        bad = sorted(n for n in sys.modules
                     if n.split('.')[0] == 'rclpy' or n.split('.')[0].endswith('_msgs'))
        print(' '.join(bad))
    """)
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '', f'core modules loaded ROS modules: {out.stdout}'


ECHO = textwrap.dedent("""
    import sys, rclpy
    from rclpy.qos import QoSProfile, DurabilityPolicy, ReliabilityPolicy
    from crtk_msgs.msg import OperatingState, StringStamped
    rclpy.init()
    node = rclpy.create_node('crtk_echo')
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub_s = node.create_publisher(OperatingState, 'echo/operating_state', qos)
    pub_c = node.create_publisher(StringStamped, 'echo/state_command', qos)
    node.create_subscription(OperatingState, 'operating_state', pub_s.publish, 10)
    node.create_subscription(StringStamped, 'state_command', pub_c.publish, 10)
    print('ready', flush=True)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    node.destroy_node()
    rclpy.try_shutdown()
""")


def test_crtk_messages_round_trip_between_processes(ros, launch, tmp_path):
    from crtk_msgs.msg import OperatingState, StringStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    script = tmp_path / 'echo.py'
    script.write_text(ECHO)
    echo = launch(sys.executable, str(script))
    node = ros.node('crtk_client')
    got = {}
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(OperatingState, 'echo/operating_state',
                             lambda m: got.setdefault('state', m), qos)
    node.create_subscription(StringStamped, 'echo/state_command',
                             lambda m: got.setdefault('command', m), qos)
    pub_s = node.create_publisher(OperatingState, 'operating_state', 10)
    pub_c = node.create_publisher(StringStamped, 'state_command', 10)
    assert wait_for(lambda: pub_s.get_subscription_count() and pub_c.get_subscription_count(),
                    20.0), echo.log()
    state = OperatingState(state='ENABLED', is_homed=True, is_busy=False)
    state.header.stamp.sec, state.header.frame_id = 42, 'PSM1_base'
    command = StringStamped(string='home')
    command.header.stamp.nanosec = 7

    def publish_until_echoed():
        if 'state' not in got:
            pub_s.publish(state)
        if 'command' not in got:
            pub_c.publish(command)
        return len(got) == 2

    assert wait_for(publish_until_echoed, 20.0, period=0.2), echo.log()
    assert got['state'] == state
    assert got['command'] == command
    assert type(got['state']).__module__.startswith('crtk_msgs.msg')


def test_colcon_build_installs_every_node_executable(ros, launch, tmp_path):
    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent))
    assert colcon, 'colcon-common-extensions is part of the environment'
    src = tmp_path / 'ws' / 'src' / 'suture_lfd'
    files = subprocess.run(['git', 'ls-files', '-co', '--exclude-standard'], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split()
    for rel in files:
        if (REPO / rel).is_file():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, src / rel)
    ws = tmp_path / 'ws'
    result = subprocess.run(
        [colcon, 'build', '--packages-select', 'suture_lfd',
         '--event-handlers', 'console_direct-'],
        cwd=ws, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    install = ws / 'install' / 'suture_lfd'
    exes = node_executables()
    assert 'footpedals' in exes
    for exe in exes:
        path = install / 'lib' / 'suture_lfd' / exe
        assert path.is_file() and os.access(path, os.X_OK), f'missing {path}'
    assert (install / 'share' / 'suture_lfd' / 'package.xml').is_file()
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'suture_lfd').is_file()
    # ros2 run suture_lfd footpedals --ros-args -r __node:=... -r __ns:=...
    site = next((install / 'lib').glob('python3*/site-packages'))
    proc = launch(str(install / 'lib' / 'suture_lfd' / 'footpedals'), '--ros-args',
                  '-r', '__node:=pedals_renamed', '-r', '__ns:=/colcon_test',
                  env={'PYTHONPATH': f'{site}{os.pathsep}{os.environ.get("PYTHONPATH", "")}',
                       'AMENT_PREFIX_PATH': f'{install}{os.pathsep}{sys.prefix}'},
                  cwd=tmp_path)
    node = ros.node('graph_probe')
    found = wait_for(lambda: ('pedals_renamed', '/colcon_test') in
                     node.get_node_names_and_namespaces(), 20.0)
    assert found, proc.log()
    assert proc.stop() == SIGINT_EXIT, proc.log()


def test_node_process_stops_cleanly_and_leaves_nothing_behind(launch):
    from harness import RosHarness

    shm = Path('/dev/shm')
    before = {p.name for p in shm.glob('*fastrtps*')} if shm.is_dir() else set()
    proc = launch('footpedals')
    probe = RosHarness()
    try:
        node = probe.node('leak_probe')
        assert wait_for(lambda: 'footpedals' in node.get_node_names(), 20.0), proc.log()
    finally:
        probe.close()
    assert proc.stop() == SIGINT_EXIT, proc.log()
    with pytest.raises(ProcessLookupError):
        os.killpg(proc.pid, 0)
    after = {p.name for p in shm.glob('*fastrtps*')} if shm.is_dir() else set()
    assert after <= before, f'stale Fast DDS files: {sorted(after - before)}'


def test_footpedal_presses_can_be_emulated(ros, launch):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Joy

    proc = launch('footpedals')
    node = ros.node('pedal_client')
    presses = []
    latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(Joy, '/footpedals/coag', lambda m: presses.append(m.buttons[0]),
                             latched)
    emulate = node.create_publisher(Joy, '/console/emulate_operator_present', 10)
    assert wait_for(lambda: emulate.get_subscription_count() > 0, 20.0), proc.log()
    emulate.publish(Joy(buttons=[7]))  # malformed: ignored, node keeps running
    emulate.publish(Joy(buttons=[1]))
    emulate.publish(Joy(buttons=[0]))
    assert wait_for(lambda: presses == [1, 0], 10.0), (presses, proc.log())
    assert proc.running()


def test_lint_is_clean():
    ruff = shutil.which('ruff', path=str(Path(sys.executable).parent))
    result = subprocess.run([ruff, 'check', '--no-cache', '.'], cwd=REPO,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_main_job_command_starts():
    result = subprocess.run([str(REPO / 'suture-lfd'), 'study', '--help'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert 'study' in result.stdout


def test_wrapper_passes_cli_subcommands_through(tmp_path):
    result = subprocess.run([str(REPO / 'suture-lfd'), 'bag', 'info', str(tmp_path / 'none')],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert 'unknown command' not in result.stderr
    assert 'no such bag' in result.stderr, result.stderr
    result = subprocess.run([str(REPO / 'suture-lfd'), 'no-such-command'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and 'no-such-command' in result.stderr


# --- setup: bad input gets a clear message ---------------------------------------------------

def _shim_path(tmp_path, drop=(), extra=None):
    """PATH with the tools setup.sh uses, minus ``drop``, plus fake commands in ``extra``."""
    shims = tmp_path / 'bin'
    shims.mkdir(exist_ok=True)
    for tool in ('bash', 'sh', 'uname', 'sha256sum', 'cut', 'cat', 'find', 'sort', 'xargs',
                 'mktemp', 'grep', 'sed', 'id', 'rm', 'touch', 'dirname', 'tail', 'printf',
                 'python3', 'cc', 'gcc', 'c++', 'g++', 'make', 'cmake', 'env'):
        real = shutil.which(tool)
        if real and tool not in drop and not (shims / tool).exists():
            (shims / tool).symlink_to(real)
    for name, body in (extra or {}).items():
        (shims / name).unlink(missing_ok=True)
        (shims / name).write_text('#!/bin/sh\n' + body + '\n')
        (shims / name).chmod(0o755)
    return str(shims)


def run_setup(tmp_path, **env):
    base = {'PATH': os.environ['PATH'], 'HOME': str(tmp_path),
            'SUTURE_LFD_VENV': str(tmp_path / 'venv'),
            'PYTHON': str(Path(sys.base_prefix) / 'bin' / 'python3')}
    return subprocess.run(['bash', str(REPO / 'tools' / 'setup.sh')],
                          env={**base, **env}, capture_output=True, text=True, timeout=300)


def test_setup_rejects_an_unsupported_python(tmp_path):
    fake = tmp_path / 'python3.9'
    fake.write_text('#!/bin/sh\necho 3.9\n')
    fake.chmod(0o755)
    result = run_setup(tmp_path, PYTHON=str(fake))
    assert result.returncode != 0
    assert 'Python 3.9 is not supported' in result.stderr
    assert 'CPython 3.10-3.12' in result.stderr


def test_setup_rejects_an_unsupported_cpu_architecture(tmp_path):
    path = _shim_path(tmp_path, drop=('uname',), extra={
        'uname': 'if [ "$1" = -m ]; then echo aarch64; else echo Linux; fi'})
    result = run_setup(tmp_path, PATH=path)
    assert result.returncode != 0
    assert 'CPU architecture aarch64 is not supported' in result.stderr
    assert 'x86_64' in result.stderr


def test_setup_names_a_missing_compiler_and_cmake(tmp_path):
    path = _shim_path(tmp_path, drop=('cmake', 'c++', 'g++'),
                      extra={'apt-get': 'exit 100', 'sudo': 'exit 1'})
    result = run_setup(tmp_path, PATH=path)
    assert result.returncode != 0
    assert 'missing: cmake g++' in result.stderr, result.stderr
    assert 'could not install cmake g++' in result.stderr


def test_setup_says_when_the_registry_cannot_be_reached(tmp_path):
    probe = subprocess.run([sys.executable, '-c', textwrap.dedent("""
        import socket, sys
        try:
            socket.create_connection(('pypi.org', 443), timeout=3).close()
        except OSError:
            sys.exit(1)
    """)])
    if probe.returncode == 0:
        pytest.skip('this machine reaches the registry; the test needs a network namespace')
    result = run_setup(tmp_path, PIP_RETRIES='0', PIP_TIMEOUT='3',
                       PIP_CONFIG_FILE=os.devnull, PIP_INDEX_URL='https://pypi.org/simple')
    assert result.returncode != 0
    assert 'cannot reach the Python package registry' in result.stderr, result.stderr


def test_setup_rerun_with_nothing_to_do_says_so():
    result = subprocess.run(['bash', str(REPO / 'tools' / 'setup.sh')],
                            capture_output=True, text=True, timeout=120,
                            env={**os.environ, 'SUTURE_LFD_VENV': sys.prefix})
    assert result.returncode == 0, result.stderr
    assert 'environment up to date' in result.stderr


def test_domain_is_private_and_discovery_local():
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert os.environ['ROS_DOMAIN_ID'] == str(DOMAIN_ID) and DOMAIN_ID != 0
