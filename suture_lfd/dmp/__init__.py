"""
Dynamic movement primitives for the needle trajectory: position, unit quaternion and pose.

The equations are those of the seed paper (Ijspeert et al. 2013 position DMP, Ude et al. 2014
quaternion DMP, weights by locally weighted regression); they are written out, with the
integration scheme, in :mod:`suture_lfd.dmp.equations`; the hyper-parameters
(:class:`DmpParams`, the paper's Table I) and the file format in :mod:`suture_lfd.dmp.base`; the
primitives in :mod:`~suture_lfd.dmp.position`, :mod:`~suture_lfd.dmp.quaternion` and
:mod:`~suture_lfd.dmp.pose`. This face re-exports their public names.

Usage::

    dmp = PoseDmp(load_dmp_params(task='ii')).fit(T, P, Q)      # needle poses, world or pair frame
    T_new, P_new, Q_new = dmp.rollout(start_pose, goal_pose)      # offline, whole trajectory
    dmp.reset(start_pose, goal_pose)                              # online
    pose = dmp.step(dt, measured=measured_pose)                   # phase stopping
    dmp.set_goal(new_goal_pose)                                   # goal switching (filtered)

Units: positions m, angles rad, time s. Quaternions (x, y, z, w). Poses are 7-vectors
``(x, y, z, qx, qy, qz, qw)`` in the frame the demonstration was given in.
"""

from suture_lfd.dmp.base import (
    FORMAT,
    FORMAT_VERSION,
    MIN_FIT_POINTS,
    ORIENTATION_FORMS,
    DmpParams,
)
from suture_lfd.dmp.equations import (
    basis_activations,
    basis_centres,
    basis_widths,
    canonical_phase,
    forcing_term,
    guarded_scale,
    least_squares_weights,
    linear_recurrence,
    lwr_weights,
    nonlinear_rate,
    normalised_features,
    position_forcing_target,
    quaternion_forcing_target,
    transition_matrices,
    uniform_features,
)
from suture_lfd.dmp.pose import PoseDmp, load_dmp, load_dmp_params
from suture_lfd.dmp.position import PositionDmp
from suture_lfd.dmp.quaternion import QuaternionDmp

__all__ = [
    'DmpParams', 'PositionDmp', 'QuaternionDmp', 'PoseDmp', 'load_dmp', 'load_dmp_params',
    'FORMAT', 'FORMAT_VERSION', 'MIN_FIT_POINTS', 'ORIENTATION_FORMS',
    'canonical_phase', 'basis_centres', 'basis_widths', 'basis_activations',
    'normalised_features', 'uniform_features', 'forcing_term', 'guarded_scale', 'lwr_weights',
    'least_squares_weights', 'position_forcing_target', 'quaternion_forcing_target',
    'nonlinear_rate', 'transition_matrices', 'linear_recurrence',
]
