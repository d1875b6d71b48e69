"""
The study report's section on the needle turning in the jaw (the needle-in-tissue realism).

With the tissue realism on, a throw's record lists its slips (``ThrowRecord.slips``). The
section counts, per method, the throws that slipped, by the arm that held the needle when it
did -- PSM2 during the puncture and the insertion (subtasks i-ii), PSM1 during the extraction
(iii-iv) -- the slip episodes, how many slipped throws completed all the same (the executor
follows the grasp it sees and aims the needle along its arc; the score's tolerances take a
few degrees of turn), the failures of the others and the grasps broken.
"""

from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

from suture_lfd.study import tables
from suture_lfd.study.records import Record, ThrowRecord

#: Subtasks during which an arm holds the needle alone in a throw.
_PHASE = {'PSM2': 'i-ii', 'PSM1': 'iii-iv'}


def slip_counts(rows: Sequence[ThrowRecord]) -> dict[str, Any]:
    """
    Count the slips of one method's throws.

    Parameters
    ----------
    rows : list of ThrowRecord
        Executed throws.

    Returns
    -------
    dict
        ``throws``, ``slipped`` (throws with a slip), ``by_phase`` (``'i-ii'``, ``'iii-iv'``:
        throws with a slip while that arm held the needle), ``episodes``, ``complete`` (slipped
        throws that completed), ``failures`` (failure -> slipped throws that failed so),
        ``broken`` (slips that broke the grasp).

    """
    slipped = [r for r in rows if r.slips]
    by_phase = {phase: sum(1 for r in slipped if any(s.get('arm') == arm for s in r.slips or ()))
                for arm, phase in _PHASE.items()}
    return {'throws': len(rows), 'slipped': len(slipped), 'by_phase': by_phase,
            'episodes': sum(len(r.slips or ()) for r in slipped),
            'complete': sum(1 for r in slipped if not r.failure),
            'failures': dict(Counter(r.failure for r in slipped if r.failure)),
            'broken': sum(1 for r in slipped for s in r.slips or () if s.get('broken'))}


def report_section(records: Sequence[Record], config: Mapping[str, Any]) -> list[str]:
    """
    Return the report's lines on slips (none when the tissue realism is off and none slipped).

    Parameters
    ----------
    records : list of Record
        The study's records.
    config : dict
        The study's configuration (its ``settings`` name the tissue preset).

    Returns
    -------
    list of str
        Markdown lines.

    """
    tissue = str(config.get('settings', {}).get('tissue', 'none'))
    rows = tables.throws(records)
    if tissue == 'none' and not any(r.slips for r in rows):
        return []
    out = []
    for method in tables.methods(records):
        c = slip_counts(tables.throws(records, method))
        fails = ', '.join(f'{k} {v}' for k, v in sorted(c['failures'].items())) or '-'
        out.append([f'`{method}`', c['throws'], c['slipped'], c['by_phase']['i-ii'],
                    c['by_phase']['iii-iv'], c['episodes'], c['complete'], fails, c['broken']])
    return ['## The needle turning in the jaw', '',
            f'Needle-in-tissue preset `{tissue}`. A throw slipped when the tissue turned the '
            'needle in the jaw past the reporting threshold; counted by the arm that held it: '
            'PSM2 (puncture and insertion, i-ii) or PSM1 (extraction, iii-iv). "Complete" '
            'slipped throws completed all the same.', '',
            tables.markdown(['method', 'throws', 'slipped', 'in i-ii', 'in iii-iv',
                             'slip episodes', 'complete', 'failed (failure: throws)',
                             'grasps broken'], out), '']

