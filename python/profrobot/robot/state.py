"""How a :class:`~profrobot.Robot` pickles and copies (its ``__getstate__`` and friends call these): format
``profrobot.Robot/1`` (:meth:`Robot.__getstate__` says what it carries), deep copies, and
the MuJoCo model and spec rebuilt from the robot's source on first use, checked against its
fingerprint. Base layer: no torch.
"""

from __future__ import annotations

import copy
from typing import Any

import mujoco

from ..errors import CorruptFileError, RobotMismatchError
from .family import model_scene_joints
from .arrays import label_fingerprint, model_arrays, object_name
from .sources import _Mjcf


STATE_FORMAT = "profrobot.Robot/1"

#: what a Robot keeps for itself only: derived scenes (at(), with_margin()), the MuJoCo reference
#: with its point cloud (pointcloud.reference_model) and, for a robot derived without compiling
#: (robot/world.py), the spec it was derived from and the edits since (an MjSpec does not pickle);
#: left out of copies, derived robots and pickles
CACHES = ("_layouts", "_margins", "_reference_model", "_reference_ids", "_spec_from", "_pose_bounds")


def getstate(self) -> dict:
    """:meth:`Robot.__getstate__` (see there)."""
    state = {k: v for k, v in self.__dict__.items()
             if k not in ("_mj_model", "_spec", "_source") + CACHES}
    source = self._source
    if source is not None and not isinstance(source.root, _Mjcf):
        try:
            source = self._source = source.loaded()  # read once, kept for later pickles
        except Exception as e:  # a file gone, unreadable, a spec to_xml refuses
            source = None
            state["_spec_lost"] = f"{type(e).__name__}: {e}"
    model = self._mj_model
    if model is None and (source is None or not source.root.exact):
        model = self.mj_model  # never the case for robots built here; compiled to be safe
    state["format"] = STATE_FORMAT
    state["source"] = source
    state["mj_model"] = None if source is not None and source.root.exact else model.__getstate__()
    return state


def setstate(self, state: dict) -> None:
    """:meth:`Robot.__setstate__` (see there)."""
    state = dict(state)
    fmt = state.pop("format", None)
    if fmt != STATE_FORMAT:
        raise CorruptFileError(f"not a pickled profrobot Robot of format {STATE_FORMAT!r} (got {fmt!r}); "
                               "it was written by another profrobot version")
    model, source = state.pop("mj_model"), state.pop("source")
    if model is not None:
        data, model = model, mujoco.MjModel.__new__(mujoco.MjModel)
        model.__setstate__(data)
    self.__dict__.update(state)
    self._mj_model, self._spec, self._source = model, None, source


def shallow_copy(self) -> Any:
    """:meth:`Robot.__copy__` (see there)."""
    new = object.__new__(type(self))
    new.__dict__.update(self.__dict__)
    return new


def with_core(self, arrays: dict, core: Any, *, keep: tuple[str, ...] = ()) -> Any:
    """A robot like this one (its caches left out, those in ``keep`` aside) whose collision model
    is ``core``, built from ``arrays``: its pairs and fingerprint follow them (``with_points``,
    ``robot/world.py``)."""
    new = object.__new__(type(self))
    new.__dict__.update({k: v for k, v in self.__dict__.items() if k not in CACHES or k in keep})
    new._arrays = arrays
    new.core = core
    new.pair_geoms, new.pair_is_self, new.pair_margin = core.pairs()
    new.fingerprint = label_fingerprint(self.joint_names, arrays, self.scene_joints)
    return new


def deep_copy(self, memo: dict) -> Any:
    """:meth:`Robot.__deepcopy__` (see there)."""
    new = object.__new__(type(self))
    memo[id(self)] = new
    for key, value in self.__dict__.items():
        if key in CACHES:  # built again on first use
            continue
        if key == "_spec":
            value = None if value is None else value.copy()
        elif key != "_source":  # immutable; its root may be an MjSpec, which deepcopy cannot copy
            value = copy.deepcopy(value, memo)
        new.__dict__[key] = value
    return new


def _fingerprint(self, model: mujoco.MjModel) -> str:
    """The label fingerprint ``model`` (with this robot's point cloud) would have."""
    names = [object_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(model.njnt)]
    arrays = model_arrays(model)
    if self.cloud is not None and len(self.cloud):
        arrays.update(self.cloud.core_arrays(self.margin))
    return label_fingerprint(names, arrays, tuple(n for n in names if n in model_scene_joints(model)))


def _from_ancestor(self) -> tuple[mujoco.MjSpec, mujoco.MjModel] | None:
    """The spec and model of a robot derived without compiling (``robot/world.py``), from the spec
    of the robot it was derived from and the edits since (a copy: the ancestor's is untouched):
    a compile, where the source would also parse every mesh again. None where that spec no longer
    gives this robot (edited in place since)."""
    ancestor = self.__dict__.get("_spec_from")
    if ancestor is None:
        return None
    spec = ancestor[0].copy()
    try:
        for edit in ancestor[1]:
            edit.add_to(spec)
        model = spec.compile()
    except Exception:
        return None
    return (spec, model) if _fingerprint(self, model) == self.fingerprint else None


def restore(self) -> None:
    """Rebuild the MjSpec (and the MjModel, if the pickle left it out) from the source, and
    check that it compiles to this very robot."""
    built = _from_ancestor(self)
    if built is not None:
        self._spec, model = built
        if self._mj_model is None:
            self._mj_model = model
        return
    try:
        spec = self._source.spec()
        model = spec.compile()
    except Exception as e:
        raise CorruptFileError(f"{self.name}: could not rebuild the MuJoCo model from the MJCF this robot "
                               f"carries: {type(e).__name__}: {e}") from e
    if _fingerprint(self, model) != self.fingerprint:
        how = ("its MjSpec, written out with MjSpec.to_xml (6 significant digits), compiles to another robot"
               if not self._source.loaded().root.exact else
               "the MJCF files it was built from now compile to another robot (edited since, another MuJoCo "
               "version, or its spec was edited after the robot was built)")
        raise RobotMismatchError(f"{self.name}: cannot rebuild the MuJoCo model of this robot: {how}. "
                                 "Labelling is unaffected; rebuild the robot itself for obstacles.")
    self._spec = spec
    if self._mj_model is None:
        self._mj_model = model
