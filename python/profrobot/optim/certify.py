"""Deprecated module: certification moved to :mod:`profrobot.certification` (one definition for
the whole library, torch-free). This name keeps working for one release."""

import warnings

from ..certification import CLEARANCE, PathCheck, certify_poses, check_path, path_free_at

__all__ = ["CLEARANCE", "PathCheck", "certify_poses", "check_path", "path_free_at"]

warnings.warn("profrobot.optim.certify is deprecated; use profrobot.certification", DeprecationWarning, stacklevel=2)
