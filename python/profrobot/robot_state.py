"""How a :class:`~profrobot.Robot` pickles and copies (a mixin of it): format
``profrobot.Robot/1`` (:meth:`RobotPickling.__getstate__` says what it carries), deep copies, and
the MuJoCo model and spec rebuilt from the robot's source on first use, checked against its
fingerprint. Base layer: no torch.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

import mujoco

from .errors import CorruptFileError, RobotMismatchError
from .family import model_scene_joints
from .model_arrays import label_fingerprint, model_arrays, object_name
from .sources import _Mjcf

if TYPE_CHECKING:
    from .robot import Robot

STATE_FORMAT = "profrobot.Robot/1"

#: what a Robot keeps for itself only: derived scenes (at(), with_margin()) and the MuJoCo reference
#: with its point cloud (pointcloud.reference_model); left out of copies, derived robots and pickles
CACHES = ("_layouts", "_margins", "_reference_model", "_reference_ids")


class RobotPickling:
    """:class:`~profrobot.Robot`'s pickling, copies and lazy rebuild (see there)."""

    def __getstate__(self) -> dict:
        """What a pickle of a Robot carries (format ``profrobot.Robot/1``), a dict of:

        - ``format``: ``"profrobot.Robot/1"`` (another is refused with ``CorruptFileError``);
        - what labelling needs, as built: ``core`` (the Rust ``RobotModel``, whose own pickle keeps
          every float to the bit), the flat arrays ``_arrays``, ``fingerprint``, ``name``, joint
          and body names, ``joint_types``, ``qpos_adr``, ``continuous``, ``joint_parents``,
          ``equalities``, ``tendons``, ``couplings``, ``pair_geoms``, ``pair_is_self``,
          ``pair_margin``: an unpickled robot labels at once, byte for byte like this one;
        - ``source``: how to rebuild the editable ``MjSpec`` (``MjSpec`` does not pickle, and its
          ``to_xml`` keeps 6 significant digits): the MJCF text, its included files and every
          mesh / texture file it reads, zlib-compressed, plus the obstacles added since, in order;
          None for :meth:`from_model`. Files are read once, at the first pickle, and then kept;
        - ``mj_model``: the compiled ``MjModel`` as MuJoCo's own pickle state (its binary model,
          bytes: any pickle protocol; MuJoCo's pickling aborts the process under protocols 0 and 1)
          only where the source cannot rebuild it exactly (``from_model``, ``from_spec``); for
          ``from_mjcf`` / ``from_menagerie`` / ``from_urdf`` robots (a URDF's source is its text with
          mesh names made asset names, the mesh bytes, the mimic equalities and ``<exclude>``s
          added) it is left out (the meshes are already in the
          source: half the size) and compiled again on first use of :attr:`mj_model` or
          :attr:`spec`.

        Whatever is rebuilt is checked: the rebuilt model must have this robot's fingerprint, else
        :class:`~profrobot.errors.RobotMismatchError` (e.g. a ``from_spec`` spec that its XML
        does not reproduce, or a spec edited after the robot was built). A Panda scene pickles to
        about 6 MB (the meshes' files, compressed).
        """
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

    def __setstate__(self, state: dict) -> None:
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

    def __copy__(self) -> "Robot":
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        return new

    def __deepcopy__(self, memo: dict) -> "Robot":
        """An independent robot equal to a pickled copy: the same labels, fingerprint and name,
        a copy of the MuJoCo model and of the editable spec (``MjSpec.copy``)."""
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

    def _restore(self) -> None:
        """Rebuild the MjSpec (and the MjModel, if the pickle left it out) from the source, and
        check that it compiles to this very robot."""
        try:
            spec = self._source.spec()
            model = spec.compile()
        except Exception as e:
            raise CorruptFileError(f"{self.name}: could not rebuild the MuJoCo model from the MJCF this robot "
                                   f"carries: {type(e).__name__}: {e}") from e
        names = [object_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(model.njnt)]
        arrays = model_arrays(model)
        if self.cloud is not None and len(self.cloud):
            arrays.update(self.cloud.core_arrays(self.margin))
        if label_fingerprint(names, arrays, tuple(n for n in names if n in model_scene_joints(model))) != self.fingerprint:
            how = ("its MjSpec, written out with MjSpec.to_xml (6 significant digits), compiles to another robot"
                   if not self._source.loaded().root.exact else
                   "the MJCF files it was built from now compile to another robot (edited since, another MuJoCo "
                   "version, or its spec was edited after the robot was built)")
            raise RobotMismatchError(f"{self.name}: cannot rebuild the MuJoCo model of this robot: {how}. "
                                     "Labelling is unaffected; rebuild the robot itself for obstacles.")
        self._spec = spec
        if self._mj_model is None:
            self._mj_model = model
