"""Shared fixtures of the LfD tests: one real in-process demonstration per session."""

import pytest


@pytest.fixture(scope='session')
def simulation():
    """A real simulation scene (synthetic phantom), shared by the session."""
    from sim_bridge.simulation import Simulation
    sim = Simulation()
    yield sim
    sim.close()


@pytest.fixture(scope='session')
def cohort():
    from suture_lfd.demos.cohort import load_cohort
    return load_cohort()


@pytest.fixture(scope='session')
def experienced_run(simulation, cohort):
    """An experienced subject's demonstration on synth1, run in the real simulation."""
    from suture_lfd.demos.demonstrator import run_demonstration
    subject = next(s for s in cohort if s.group == 'experienced')
    return run_demonstration(simulation, subject, 'synth1', seed=0)
