"""Build script of the ament_python package suture_lfd."""

from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'suture_lfd'
HERE = Path(__file__).resolve().parent

# One console_scripts entry per node executable (ros2 run suture_lfd <name>), plus the CLI; a
# node's entry is its Executable (help before the node's module is imported).
NODES = {
    'simulator': 'sim_bridge.nodes.executables:simulator',
    'footpedals': 'sim_bridge.nodes.executables:footpedals',
    'demonstrator': 'suture_lfd.nodes.executables:demonstrator',
    'recorder': 'suture_lfd.nodes.executables:recorder',
    'player': 'suture_lfd.nodes.executables:player',
    'segmenter': 'suture_lfd.nodes.executables:segmenter',
    'executor': 'suture_lfd.nodes.executables:executor',
    'teleop': 'suture_lfd.nodes.executables:teleop',
    'mtms': 'suture_lfd.nodes.executables:mtms',
    'viewer': 'suture_lfd.nodes.executables:viewer',
    'perception': 'suture_lfd.nodes.executables:perception',
}
CLI = {
    'suture-lfd': 'suture_lfd.cli:main',
}


def interface_files():
    """List the interface definitions (.msg) that suture_lfd.bags reads for message types."""
    groups = {}
    for path in sorted((HERE / 'interfaces').glob('*/msg/*.msg')):
        dest = f'share/{PACKAGE}/interfaces/{path.parent.parent.name}/msg'
        groups.setdefault(dest, []).append(str(path.relative_to(HERE)))
    return sorted(groups.items())


def config_files():
    return sorted(str(p.relative_to(HERE)) for pattern in ('*.yaml', '*.xml')
                  for p in (HERE / 'config').glob(pattern))


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=['sim_bridge', 'sim_bridge.*', 'suture_lfd', 'suture_lfd.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', config_files()),
        *interface_files(),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='suture_lfd maintainers',
    maintainer_email='suture-lfd@users.noreply.github.com',
    description='Simulated dVRK (PyBullet, CRTK ROS 2) and learning from demonstration for '
                'autonomous suturing.',
    license='MIT',
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in {**NODES, **CLI}.items()],
    },
)
