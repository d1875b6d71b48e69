"""
The one ``main`` of every node executable: help, argument checks, signals, exit codes.

:func:`run_node` is what each executable's ``main()`` returns. In order, it

1. answers ``-h``/``--help`` with the node's summary, its parameters (name, default and comment,
   read from ``config/<node>.yaml``) and one example, and returns 0 **before** ROS is
   initialised, so that asking for help never starts a node (nor moves an arm);
2. refuses any argument outside ``--ros-args ... [--]`` (exit 2, one line on stderr), so that a
   mistyped option never starts a node with its defaults;
3. initialises rclpy **without** rclpy's own signal handlers and installs one handler for SIGINT
   and SIGTERM: while the node is being built (or runs a job of its own) the signal interrupts
   it at once; while it spins, the signal stops the spin loop between two callbacks, so a node
   is never interrupted halfway through a command it sends;
4. builds the node; a ``ValueError``, ``OSError`` or ``LookupError`` it raises (unknown pair,
   bad file, bad parameter) gives one line on stderr, ``<name>: error: <message>``, and exit 2;
   an override ``-p name:=value`` of a parameter the node does not declare is refused the same
   way, before the node spins;
5. exempts what the node built from Python's cyclic collector (:func:`_keep_start_up_objects`)
   and spins it until it is ``finished`` (a node that ends by itself sets ``finished`` and
   ``exit_code``), a signal arrives or the context is shut down;
6. after a signal calls the node's ``on_interrupt(signal_name)``: stop commanding (the arms hold
   their last setpoint, as a dVRK arm does when its servo stream stops) and write the result it
   has with outcome ``interrupted``; the exit code is 128 + the signal number (130 for SIGINT,
   143 for SIGTERM), never 0;
7. calls the node's ``on_exit()`` (close files, stop threads), destroys the nodes and shuts
   rclpy down, in that order, so nothing publishes on a context that is gone.

The optional parts of a node are declared by :class:`NodeHooks`: a node class that needs one
lists ``NodeHooks`` before ``rclpy.node.Node`` among its bases and overrides it; a node without
it runs with the defaults (no companions, spin until stopped, nothing to do at the end).
"""

import ast
from collections.abc import Sequence
from contextlib import contextmanager
import gc
import importlib
import importlib.util
import re
import signal
import sys
import textwrap
from typing import Any

from sim_bridge.common.configfile import load_yaml
from sim_bridge.common.paths import config_path
from sim_bridge.ros.dds import use_project_profile

HELP_FLAGS = ('-h', '--help')
SIGNALS = (signal.SIGINT, signal.SIGTERM)
_STARTUP_ERRORS = (ValueError, OSError, LookupError)
SWITCH_INTERVAL = 0.0005  # s a thread holds the interpreter while one waits (Python: 5 ms)
_VALUE_WIDTH = 28  # characters of a default shown in --help
_LINE = 99  # characters per line of --help


class NodeHooks:
    """
    What :func:`run_node` calls on a node besides spinning it, with the defaults.

    A node class that needs a hook lists this class before ``rclpy.node.Node`` among its bases
    and overrides the hook.

    Attributes
    ----------
    companions : sequence of rclpy.node.Node
        Further nodes spun on the same executor and destroyed with this one.
    finished : bool
        Set by a node that ends by itself: the spin loop stops and :attr:`exit_code` is the
        process's exit code.
    exit_code : int
        Exit code once :attr:`finished` (0: success).

    """

    companions: Sequence[Any] = ()
    finished: bool = False
    exit_code: int = 0

    def run(self) -> int | None:
        """
        Do the node's job in the main thread instead of spinning it; return the exit code.

        The default returns None: the node is spun.
        """
        return None

    def on_start(self) -> None:
        """Start what the node runs of its own (threads), once it is on its executor."""

    def on_interrupt(self, signal_name: str) -> None:
        """Stop commanding and write the result so far with outcome ``interrupted``."""

    def on_exit(self) -> None:
        """Release the node's resources (files, threads) before its ROS entities go."""


class Interrupted(BaseException):  # noqa: N818 (a stop request, like KeyboardInterrupt)
    """A SIGINT or SIGTERM that stops the node; ``signum`` is the signal."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def split_arguments(argv):
    """
    Split command-line arguments into the user's and ROS's.

    Parameters
    ----------
    argv : list of str
        Arguments without the program name.

    Returns
    -------
    user : list of str
        Arguments outside every ``--ros-args ... [--]`` block.
    ros : list of str
        Arguments inside them (without the ``--ros-args`` and ``--`` markers).

    """
    user, ros, inside = [], [], False
    for arg in argv:
        if arg == '--ros-args':
            inside = True
        elif arg == '--' and inside:
            inside = False
        elif inside:
            ros.append(arg)
        else:
            user.append(arg)
    return user, ros


def parameter_overrides(ros_args):
    """
    Return the parameter names set with ``-p``/``--param`` in ROS arguments.

    Parameters
    ----------
    ros_args : list of str
        Arguments inside ``--ros-args`` blocks.

    Returns
    -------
    list of (str or None, str)
        ``(node, name)``: the node a ``node:name:=value`` override is for (None: every node),
        and the parameter's name.

    """
    names = []
    for flag, value in zip(ros_args, ros_args[1:]):
        if flag in ('-p', '--param') and ':=' in value:
            target, _, name = value.split(':=', 1)[0].rpartition(':')
            names.append((target or None, name))
    return names


def _format_value(value):
    if value == '':
        return "''"
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, list):
        text = '[' + ', '.join(_format_value(v) for v in value) + ']'
    else:
        text = str(value)
    return text if len(text) <= _VALUE_WIDTH else text[:_VALUE_WIDTH - 3] + '...'


def _section_comments(lines, name):
    """Map each parameter of section ``name`` to its comment in the YAML text."""
    comments, indent, current, above, in_section, in_params = {}, None, None, [], False, False
    for line in lines:
        stripped = line.strip()
        depth = len(line) - len(line.lstrip())
        if not stripped:
            continue
        if depth == 0 and not stripped.startswith('#'):
            in_section = stripped.rstrip(':').strip('\'"') == name
            in_params = False
            continue
        if not in_section:
            continue
        if stripped == 'ros__parameters:':
            in_params = True
            continue
        if not in_params:
            continue
        if indent is None and not stripped.startswith('#'):
            indent = depth
        if stripped.startswith('#'):
            text = stripped.lstrip('#').strip()
            if current is not None and (indent is None or depth > indent):
                comments[current].append(text)
            else:
                above.append(text)
            continue
        match = re.match(r'([A-Za-z_][\w.]*):(.*)$', stripped)
        if depth == indent and match:
            current = match.group(1)
            trailing = re.search(r'\s#\s?(.*)$', match.group(2))
            comments[current] = above + ([trailing.group(1).strip()] if trailing else [])
            above = []
    return {key: ' '.join(text) for key, text in comments.items()}


def parameter_help(config_file, section):
    """
    Describe a node's parameters from its configuration file.

    Parameters
    ----------
    config_file : str
        File name in the package's ``config/`` folder (``'simulator.yaml'``).
    section : str
        The node's section in it (``'simulator'``).

    Returns
    -------
    str
        One line per parameter: name, default, comment.

    """
    path = config_path(config_file)
    data = load_yaml(path)
    params = ((data.get(section) or {}).get('ros__parameters') or {})
    comments = _section_comments(path.read_text().splitlines(), section)
    shown = {key: _format_value(value) for key, value in params.items()}
    width = max((len(k) for k in params), default=0)
    value_width = max((len(v) for v in shown.values()), default=0)
    indent = 2 + width + 3 + value_width + 2
    lines = [f'parameters (config/{config_file}; set with --ros-args -p NAME:=VALUE):']
    for key, value in shown.items():
        head = f'  {key.ljust(width)} = {value.ljust(value_width)}  '
        comment = textwrap.wrap(comments.get(key, ''), max(_LINE - indent, 30),
                                break_on_hyphens=False) or ['']
        lines.append((head + comment[0]).rstrip())
        lines.extend(' ' * indent + more for more in comment[1:])
    return '\n'.join(lines)


def help_text(name, doc, config_file, example):
    """
    Return the ``--help`` text of an executable.

    Parameters
    ----------
    name : str
        Executable name.
    doc : str
        The node module's docstring; its first paragraph is the summary.
    config_file : str or None
        The node's parameter file in ``config/`` (None: the node has no parameters).
    example : str
        One example command line.

    Returns
    -------
    str
        The text.

    """
    summary = ' '.join((doc or '').strip().split('\n\n')[0].split())
    parts = [f'usage: {name} [-h] [--ros-args [-p NAME:=VALUE ...] [-r FROM:=TO ...]]',
             summary]
    if config_file:
        parts.append(parameter_help(config_file, name))
    else:
        parts.append('parameters: none')
    parts.append(f'example:\n  {example}')
    return '\n\n'.join(p for p in parts if p) + '\n'


class _SignalState:
    """Which signal arrived, and whether it may interrupt the main thread at once."""

    def __init__(self):
        self.signum = None
        self.raise_at_once = True

    def handle(self, signum, frame):
        if self.signum is not None:
            return  # a second signal while stopping: the first one is being handled
        self.signum = signum
        # Raised inside a module lock's weakref callback (the import system's), the exception
        # would be printed as 'Exception ignored' and dropped: there the signal is only kept,
        # and takes effect when the node next checks it (at the latest when it spins).
        in_lock_callback = (frame is not None and frame.f_code.co_name == 'cb'
                            and frame.f_code.co_filename == '<frozen importlib._bootstrap>')
        if self.raise_at_once and not in_lock_callback:
            raise Interrupted(signum)

    @contextmanager
    def deferred(self):
        """Within: a signal only sets :attr:`signum` (the spin loop checks it)."""
        self.raise_at_once = False
        try:
            if self.signum is not None:
                raise Interrupted(self.signum)
            yield
        finally:
            self.raise_at_once = True


def _error(name, message):
    print(f'{name}: error: {message}', file=sys.stderr, flush=True)


def run_node(make_node, name, args=None, *, doc='', config_file=None, example=None,
             spin_period=0.1):
    """
    Run a node executable from start to exit (see the module docstring).

    Parameters
    ----------
    make_node : callable
        Builds the node, after ``rclpy.init``.
    name : str
        Executable name (also the node's section in its configuration file).
    args : list of str, optional
        Command-line arguments without the program name (default: ``sys.argv[1:]``).
    doc : str or callable
        The node module's docstring (summary of ``--help``), or a function returning it.
    config_file : str or None
        The node's file in ``config/``; None: the node has no parameters.
    example : str, optional
        One example command line for ``--help``.
    spin_period : float
        Longest wait (s) of the spin loop before it checks for a signal.

    Returns
    -------
    int
        Process exit code: the node's ``exit_code`` (0 when it ends without one), 2 when it
        cannot start, 128 + signal number after SIGINT or SIGTERM.

    """
    argv = list(sys.argv[1:] if args is None else args)
    user, ros_args = split_arguments(argv)
    if any(a in HELP_FLAGS for a in user):
        sys.stdout.write(help_text(name, doc() if callable(doc) else doc, config_file,
                                   example or name))
        return 0
    if user:
        _error(name, f'unknown argument {user[0]!r}; parameters are set with '
                     f'--ros-args -p NAME:=VALUE (see {name} --help)')
        return 2
    # The handlers stay until the process exits: a late signal only sets a flag.
    state = _SignalState()
    try:
        for each in SIGNALS:
            signal.signal(each, state.handle)
        return _run(make_node, name, [sys.argv[0], *argv], ros_args, state, spin_period)
    except Interrupted as stop:
        return 128 + stop.signum
    finally:
        state.raise_at_once = False


def _keep_start_up_objects():
    """
    Collect once, then exempt every object alive after start-up from Python's cyclic collector.

    A node keeps what it built at start-up (a scene, meshes, messages, endpoints: some 65,000
    objects in the simulator) until it exits; a full collection walks them all, and took 350 ms
    in the simulator on a busy two-core machine, a silence in its 100 Hz state that a dVRK client
    reports as stale data. Frozen, they are skipped; garbage made later is collected as before.
    """
    gc.collect()
    gc.freeze()


def _run(make_node, name, argv, ros_args, state, spin_period):
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    import rclpy.utilities

    context = rclpy.utilities.get_default_context()
    nodes, node, executor, hooks = [], None, None, NodeHooks()
    use_project_profile()  # before the participant exists (sim_bridge.ros.dds)
    try:
        rclpy.init(args=argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            node = make_node()
        except _STARTUP_ERRORS as exc:
            _error(name, str(exc))
            return 2
        if isinstance(node, NodeHooks):
            hooks = node
        nodes = [node, *hooks.companions]
        unknown = [p for target, p in parameter_overrides(ros_args)
                   if target in (None, node.get_name()) and not node.has_parameter(p)]
        if unknown:
            _error(name, f'unknown parameter {unknown[0]!r}; see {name} --help')
            return 2
        code = hooks.run()
        if code is not None:
            return code
        executor = SingleThreadedExecutor(context=context)
        for each in nodes:
            executor.add_node(each)
        _keep_start_up_objects()
        sys.setswitchinterval(SWITCH_INTERVAL)
        hooks.on_start()
        with state.deferred():
            try:
                while context.ok() and not hooks.finished:
                    executor.spin_once(timeout_sec=spin_period)
                    if state.signum is not None:
                        raise Interrupted(state.signum)
            except ExternalShutdownException:
                pass
        return hooks.exit_code
    except Interrupted as stop:
        if node is not None:
            state.raise_at_once = False  # the node writes its result: nothing may cut it short
            node.get_logger().info(f'stopped by {signal.Signals(stop.signum).name}')
            hooks.on_interrupt(signal.Signals(stop.signum).name)
        return 128 + stop.signum
    finally:
        state.raise_at_once = False
        _close(node, hooks, nodes, executor, context)


def _close(node, hooks, nodes, executor, context):
    """Release the node's resources, then its ROS entities, then the context."""
    import rclpy

    if node is not None:
        hooks.on_exit()
    if executor is not None:
        executor.shutdown(timeout_sec=1.0)
    for each in reversed(nodes):
        each.destroy_node()
    rclpy.try_shutdown(context=context)


def module_docstring(module):
    """
    Return a module's docstring without importing it (read from its source).

    Parameters
    ----------
    module : str
        Dotted module name.

    Returns
    -------
    str
        The docstring ('' if it has none).

    """
    spec = importlib.util.find_spec(module)
    if spec is None or not spec.origin:
        return ''
    with open(spec.origin, encoding='utf-8') as source:
        return ast.get_docstring(ast.parse(source.read())) or ''


class Executable:
    """
    The console-script ``main`` of a node whose module is imported only when the node runs.

    ``--help`` is answered from the module's source and ``config/<name>.yaml`` without importing
    the module (the executor's imports take seconds on a busy machine); otherwise the node class
    is imported after the signal handlers are in place, so a stop during start-up is clean too.

    Parameters
    ----------
    name : str
        Executable name.
    target : str
        ``'package.module:NodeClass'``; the class (or factory) :func:`run_node` builds.
    config_file : str, optional
        The node's file in ``config/``.
    example : str, optional
        One example command line for ``--help``.

    """

    def __init__(self, name, target, *, config_file=None, example=None):
        self.name = name
        self.target = target
        self.config_file = config_file
        self.example = example

    def make_node(self):
        """Import the node's module and build the node."""
        module, _, attribute = self.target.partition(':')
        return getattr(importlib.import_module(module), attribute)()

    def __call__(self, args=None):
        module = self.target.partition(':')[0]
        return run_node(self.make_node, self.name, args,
                        doc=lambda: module_docstring(module), config_file=self.config_file,
                        example=self.example)
