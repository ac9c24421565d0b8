"""The closed loop as an SSP (System Structure and Parameterization 1.0, Modelica Association):
one ``.ssp`` archive that other co-simulation tools (Ecos, libcosim, OMSimulator, ...) run.

Writing (:mod:`.write`: :func:`export_ssp`) and reading (:mod:`.read`: :func:`read_ssp`, an
archive ours or another tool's, hostile until checked) share only :mod:`.common` (namespaces,
units, schemas); :mod:`.system` runs the system an archive describes (``simulate LOOP.ssp``).
"""

from furuta_cosim.ssp.common import base_unit
from furuta_cosim.ssp.read import SspPlant, is_ssp, on_ssp, open_archive, read_ssp, split_ssp
from furuta_cosim.ssp.write import export_ssp

__all__ = ["SspPlant", "base_unit", "export_ssp", "is_ssp", "on_ssp", "open_archive", "read_ssp", "split_ssp"]
