"""
The executor's watchdog as plain logic: arrivals and times in, verdicts out.

Each case plays a timeline of ``measured_cp`` and ``/clock`` arrivals (simulation stamps, wall
times) such as a live, a dead, a silent or a starved simulator makes.
"""

import subprocess
import sys

import pytest
from sim_bridge.ros.peer import ProcessWatch, announcement
from suture_lfd.skill.watchdog import ArmWatchdog

ARMS = ('PSM1', 'PSM2')
RATE = 100.0


def watchdog():
    return ArmWatchdog(ARMS, RATE, stale_timeout=0.1, clock_timeout=1.0, starved_timeout=30.0)


def play(dog, t0, t1, wall0, clock=True, arms=ARMS, rtf=1.0):
    """Run the simulator from simulation time t0 to t1 (100 Hz), checking at each step."""
    verdicts = []
    n = int(round((t1 - t0) * RATE))
    for k in range(n + 1):
        t = t0 + k / RATE
        now = wall0 + (t - t0) / rtf
        if clock:
            dog.clock(t, now)
        for a in arms:
            dog.measured(a, t, now)
        verdict = dog.check(now, t)
        if verdict is not None:
            verdicts.append(verdict)
    return verdicts


def test_a_live_simulator_gives_no_verdict():
    dog = watchdog()
    assert play(dog, 0.0, 2.0, 100.0) == []
    assert play(watchdog(), 0.0, 2.0, 100.0, clock=False) == []


def test_an_arm_silent_while_the_clock_runs_halts_the_throw():
    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    verdicts = play(dog, 1.01, 1.5, 101.01, arms=('PSM1',))  # PSM2 stops answering
    assert verdicts and verdicts[0].halt
    assert 'the arms stopped answering' in verdicts[0].reason
    assert verdicts[0].details['silence_s'] == pytest.approx(0.11, abs=0.011)


def test_a_settling_throw_waits_ten_times_longer_for_a_silent_arm():
    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    for k in range(1, 60):   # 0.59 s of clock without PSM2
        t, now = 1.0 + k / RATE, 101.0 + k / RATE
        dog.clock(t, now)
        dog.measured('PSM1', t, now)
        assert dog.check(now, 1.0, settling=True) is None
    for k in range(60, 200):
        t, now = 1.0 + k / RATE, 101.0 + k / RATE
        dog.clock(t, now)
        verdict = dog.check(now, 1.0, settling=True)
        if verdict is not None:
            break
    assert verdict is not None and verdict.halt and 1.0 < verdict.details['silence_s'] < 1.03


def test_a_stalled_machine_is_not_a_dead_arm():
    """Clock and arms stop together for 0.8 s of wall time (below clock_timeout): no verdict."""
    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    for k in range(80):
        assert dog.check(101.0 + k / RATE, 1.0) is None
    assert play(dog, 1.01, 2.0, 101.81) == []


def test_a_stopped_simulator_halts_after_the_clock_timeout():
    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    verdict = None
    for k in range(1, 200):
        verdict = dog.check(101.0 + k / RATE, 1.0)
        if verdict is not None:
            break
    assert verdict.halt and 'the simulator stopped' in verdict.reason
    assert verdict.details['wall_silence_s'] == pytest.approx(1.0, abs=0.02)


def test_an_exited_simulator_process_halts_at_once_and_a_running_one_is_waited_for():
    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    child = subprocess.Popen([sys.executable, '-c', 'pass'])
    gone = ProcessWatch(announcement(child.pid))
    child.wait()
    verdicts = [dog.check(101.0 + k / RATE, 1.0, process=gone) for k in range(1, 30)]
    first = next(v for v in verdicts if v is not None)
    assert first.halt and f'process {child.pid} exited' in first.reason
    assert first.details['wall_silence_s'] == pytest.approx(0.11, abs=0.02)

    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    starved = ProcessWatch(announcement())  # this very process: it runs
    said = []
    for k in range(1, 3200):
        verdict = dog.check(101.0 + k / RATE, 1.0, process=starved)
        if verdict is not None:
            said.append(verdict)
            if verdict.halt:
                break
    # one warning at the clock timeout, then silence until starved_timeout, then a halt
    assert len(said) == 2, said
    assert not said[0].halt and 'waiting for it' in said[0].reason
    assert said[0].details['wall_silence_s'] == pytest.approx(1.0, abs=0.02)
    assert said[1].halt and said[1].details['wall_silence_s'] > 30.0


def test_a_late_check_is_the_caller_s_delay_not_the_simulator_s():
    """The controller itself was busy 3 s (planning): arrivals are still queued."""
    dog = watchdog()
    play(dog, 0.0, 1.0, 100.0)
    assert dog.check(104.0, 1.0) is None


def test_without_a_clock_the_silence_is_estimated_from_the_simulation_rate():
    dog = watchdog()
    play(dog, 0.0, 2.0, 100.0, clock=False, rtf=0.25)   # quarter real time
    for k in range(1, 20):    # checked on time for 0.2 s of wall time since the last arrival
        dog.silence(108.0 + k / RATE)
    silence, quiet = dog.silence(108.0 + 0.2)
    assert quiet is None
    assert silence == pytest.approx(0.05, abs=0.01)   # 0.2 s of wall at 0.25


def test_bad_settings_are_refused_with_their_names():
    with pytest.raises(ValueError, match='stale_timeout must be > 0'):
        ArmWatchdog(ARMS, RATE, 0.0, 1.0, 30.0)
