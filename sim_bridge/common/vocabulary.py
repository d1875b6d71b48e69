"""
The project's names, stated once: arms, the suturing subtasks, the tasks a skill learns.

Every module that names arms or subtasks takes them from here, so that a new arm or a renamed
subtask is one edit.
"""

#: The patient-side manipulators, in the order the simulator creates them.
PSMS: tuple[str, ...] = ('PSM1', 'PSM2')

#: Every simulated arm: the PSMs and the endoscope camera manipulator.
ARMS: tuple[str, ...] = ('PSM1', 'PSM2', 'ECM')

#: The five suturing subtasks of the seed paper: (i) pick up and reach the entry point,
#: (ii) insert to the exit point, (iii) regrasp, (iv) extract, (v) hand over.
SUBTASKS: tuple[str, ...] = ('i', 'ii', 'iii', 'iv', 'v')

#: The subtasks whose needle trajectories a skill learns as DMPs (insertion and extraction).
TASKS: tuple[str, ...] = ('ii', 'iv')
