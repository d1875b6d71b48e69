"""
The direction of imports, read from the source (AST, lazy imports inside functions included).

- ``sim_bridge`` never imports ``suture_lfd`` (the pipeline depends on the simulator, never the
  other way).
- Core modules never import rclpy or a message package; only the nodes (``*/nodes/``) and the
  ROS layer (``sim_bridge/ros/``) do. (``test_package.py`` checks the same at run time, in a
  fresh interpreter.)
- Only the nodes and the ROS layer itself import the ROS layer.
- No circle between subpackages (a subpackage, or a top-level module, is one unit).

The last tests add a temporary module with one forbidden import to a copy of the tree and show
that the check names it.
"""

import ast
import shutil
import textwrap

from harness import REPO
import pytest

PACKAGES = ('sim_bridge', 'suture_lfd')
ROS_LAYER = 'sim_bridge.ros'
# Top-level names of ROS client libraries and interface packages besides the ``*_msgs`` ones.
ROS_NAMES = {'rclpy', 'rcl_interfaces', 'std_srvs', 'builtin_interfaces', 'rosidl_runtime_py',
             'crtk_msgs', 'tf2_msgs', 'lifecycle_msgs'}


def modules(root):
    """Map each module's dotted name to its path, for both packages under ``root``."""
    found = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob('*.py')):
            rel = path.relative_to(root).with_suffix('')
            found['.'.join(rel.parts).removesuffix('.__init__')] = path
    return found


def imported_names(name, path):
    """Yield every absolute module name that the module imports (relative ones resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parts = package.split('.')
                parts = parts[:len(parts) - node.level + 1]
                base = '.'.join(parts + ([base] if base else []))
            yield base
            for alias in node.names:  # `from pkg import module`
                yield f'{base}.{alias.name}'


def is_ros(name):
    top = name.split('.')[0]
    return top in ROS_NAMES or top.endswith('_msgs')


def is_face(name):
    """True for the nodes and the ROS layer, the modules allowed to import ROS."""
    parts = name.split('.')
    return 'nodes' in parts or name == ROS_LAYER or name.startswith(ROS_LAYER + '.')


def unit(name):
    """The subpackage (or top-level module) a module belongs to: ``suture_lfd.dmp``."""
    return '.'.join(name.split('.')[:2])


def violations(root):
    """Return the broken rules of the tree under ``root``, one readable line each."""
    mods = modules(root)
    found = []
    graph = {}
    for name, path in mods.items():
        for target in sorted(set(imported_names(name, path))):
            if name.startswith('sim_bridge') and target.split('.')[0] == 'suture_lfd':
                found.append(f'{name} imports {target}: sim_bridge never imports suture_lfd')
            if is_ros(target) and not is_face(name):
                found.append(f'{name} imports {target}: only nodes and {ROS_LAYER} import ROS')
            if (target == ROS_LAYER or target.startswith(ROS_LAYER + '.')) and not is_face(name):
                found.append(f'{name} imports {target}: only nodes import the ROS layer')
            if target.split('.')[0] in PACKAGES and unit(target) != unit(name) \
                    and (target in mods or unit(target) in mods):
                graph.setdefault(unit(name), set()).add(unit(target))
    found.extend(f'import circle: {" -> ".join(c)}' for c in circles(graph))
    return sorted(set(found))


def circles(graph):
    """Return one closed path for each strongly connected group of more than one unit."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(v):  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group) + [sorted(group)[0]])

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_the_tree_keeps_the_import_rules():
    mods = modules(REPO)
    assert 'sim_bridge.simulation' in mods and 'suture_lfd.planning.expert' in mods
    assert violations(REPO) == []


@pytest.fixture
def tree(tmp_path):
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns('__pycache__'))
    assert violations(tmp_path) == []
    return tmp_path


@pytest.mark.parametrize('where, source, message', [
    ('sim_bridge/probe.py', 'from suture_lfd.dmp import PoseDmp\n',
     'sim_bridge.probe imports suture_lfd.dmp: sim_bridge never imports suture_lfd'),
    ('sim_bridge/scene/probe.py', 'def f():\n    import suture_lfd.cli\n',
     'sim_bridge.scene.probe imports suture_lfd.cli: sim_bridge never imports suture_lfd'),
    ('suture_lfd/dmp/probe.py', 'import rclpy\n',
     'suture_lfd.dmp.probe imports rclpy: only nodes and sim_bridge.ros import ROS'),
    ('sim_bridge/probe.py', 'from geometry_msgs.msg import Pose\n',
     'sim_bridge.probe imports geometry_msgs.msg: only nodes and sim_bridge.ros import ROS'),
    ('suture_lfd/study/probe.py', 'from sim_bridge.ros import conversions\n',
     'suture_lfd.study.probe imports sim_bridge.ros: only nodes import the ROS layer'),
])
def test_a_forbidden_import_in_a_temporary_module_is_named(tree, where, source, message):
    (tree / where).write_text(textwrap.dedent(source))
    assert message in violations(tree)


def test_a_circle_made_by_a_temporary_module_is_named(tree):
    (tree / 'suture_lfd/dmp/probe.py').write_text('from suture_lfd.skill import learn_skill\n')
    found = violations(tree)
    assert len(found) == 1 and found[0].startswith('import circle: ')
    assert {'suture_lfd.dmp', 'suture_lfd.skill'} <= set(found[0].split(': ')[1].split(' -> '))


def test_an_import_within_one_subpackage_is_no_circle(tree):
    (tree / 'suture_lfd/dmp/probe.py').write_text('from suture_lfd.dmp import base\n')
    assert violations(tree) == []


def test_the_rules_read_relative_imports(tree):
    (tree / 'sim_bridge/kinematics/probe.py').write_text('from ..ros import params\n')
    rule = 'only nodes import the ROS layer'
    assert set(violations(tree)) == {
        f'sim_bridge.kinematics.probe imports sim_bridge.ros: {rule}',
        f'sim_bridge.kinematics.probe imports sim_bridge.ros.params: {rule}'}


# --- module size ---------------------------------------------------------------------------------

LONG_MODULE = 500  # lines; a longer module says in its docstring why it stays one file


def long_modules_without_reason(root):
    """Return the modules over ``LONG_MODULE`` lines whose docstring has no ``Size:`` sentence."""
    found = []
    for name, path in modules(root).items():
        text = path.read_text()
        if text.count('\n') <= LONG_MODULE:
            continue
        doc = ast.get_docstring(ast.parse(text, filename=str(path))) or ''
        if 'Size:' not in doc:
            found.append(f'{name}: {text.count(chr(10))} lines and no "Size:" sentence in its '
                         'docstring saying why it is one file')
    return found


def test_every_module_over_500_lines_says_why_it_is_one_file():
    assert long_modules_without_reason(REPO) == []


def test_a_long_module_without_a_reason_is_named(tree):
    body = '\n'.join(f'X{k} = {k}' for k in range(LONG_MODULE + 1))
    (tree / 'suture_lfd/dmp/long.py').write_text(f'"""A long module."""\n{body}\n')
    (tree / 'suture_lfd/dmp/long_ok.py').write_text(
        f'"""\nA long module.\n\nSize: one table of constants.\n"""\n{body}\n')
    assert [line.split(':')[0] for line in long_modules_without_reason(tree)] == [
        'suture_lfd.dmp.long']


# --- private names -------------------------------------------------------------------------------

def private_imports(root):
    """Return every ``from <package module> import _name`` of the tree, one line each."""
    found = []
    for name, path in modules(root).items():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module \
                    and node.module.split('.')[0] in PACKAGES:
                found += [f'{name} imports {alias.name} from {node.module}' for alias in node.names
                          if alias.name.startswith('_') and not alias.name.startswith('__')]
    return found


def test_no_module_imports_a_private_name_of_another():
    assert private_imports(REPO) == []


def test_a_private_import_in_a_temporary_module_is_named(tree):
    (tree / 'suture_lfd/dmp/probe.py').write_text(
        'from sim_bridge.common.geometry import _jinv_coefficient\n')
    assert private_imports(tree) == [
        'suture_lfd.dmp.probe imports _jinv_coefficient from sim_bridge.common.geometry']
