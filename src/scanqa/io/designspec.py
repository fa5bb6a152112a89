"""Design specs (TOML, ``format = "scanqa-design-spec/1"``): what an optimised scanner
must cover and what may change (:mod:`scanqa.design.optimisation`, ``scanqa design
optimise``).

Example::

    format = "scanqa-design-spec/1"
    objective = "usable_volume"       # or "worst_sigma"
    level = 0.49                      # combined attenuation threshold A_c A_p [-]
    sigma_max_um = 3.0                # largest sigma on the line of sight in the box [um]
    step_mm = 2.0                     # voxel size of the usable volume [mm]
    [cover]                           # the volume to cover [mm], scanner frame
    min_mm = [-15.0, -15.0, 440.0]
    max_mm = [15.0, 15.0, 460.0]
    [limits]                          # settings that vary, [low, high] in their units
    camera_focus_mm = [400.0, 520.0]
    [[obstacles]]                     # boxes no view pyramid may cross [mm]
    min_mm = [60.0, -100.0, 150.0]
    max_mm = [120.0, 100.0, 200.0]

This module reads the file and checks it against :data:`SCHEMA`; which settings may
vary (the names under ``[limits]``) and the order of the bounds are checked by
:class:`scanqa.design.optimisation.DesignSpec`.
"""

from __future__ import annotations

import os

from scanqa.io.schema import Field, Schema, count, declare, greater, within
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-design-spec/1"
_BOX = (Field("min_mm", "numbers", "mm", required=True, check=count(3),
              doc="the box's lower corner"),
        Field("max_mm", "numbers", "mm", required=True, check=count(3),
              doc="the box's upper corner"))
#: The design spec's keys (module notes).
SCHEMA = declare(Schema("design spec", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("objective", "string", default="usable_volume",
          doc='"usable_volume" (maximised) or "worst_sigma" (minimised)'),
    Field("level", "number", "-", default=0.49, check=within(0, 1),
          doc="combined attenuation threshold A_c A_p, in (0, 1)"),
    Field("sigma_max_um", "number", "um", required=True, check=greater(0),
          doc="largest sigma on the line of sight in the box"),
    Field("step_mm", "number", "mm", default=2.0, check=greater(0),
          doc="voxel size of the usable volume"),
    Field("cover", "table", required=True, table=Schema("[cover]", _BOX),
          doc="the volume to cover, scanner frame"),
    Field("limits", "table", required=True, doc="the settings that vary",
          table=Schema("[limits]", (), open=True, each=Field(
              "SETTING", "numbers", check=count(2),
              doc="[low, high] of a scanner setting, in its unit"))),
    Field("obstacles", "tables", table=Schema("[[obstacles]]", _BOX),
          doc="boxes no view pyramid may cross"),
), formats=(FORMAT,)))


def read_design_spec(path: str | os.PathLike) -> dict:
    """Read a design spec and check it against :data:`SCHEMA`.

    Parameters
    ----------
    path : str or PathLike
        The TOML file.

    Returns
    -------
    dict
        The parsed file, keys and value types checked.

    Raises
    ------
    InputError
        Unreadable file, wrong format, unknown or missing key, a wrongly typed value.
    """
    return SCHEMA.validate(read_toml(path, "design spec"), path)
