"""The pendulum FMU runs unchanged in Ecos (a C++ engine no one here wrote) and in fmpy."""


from furuta_cosim.fmu.check import ecos_available, relative_difference, run_ecos, run_fmpy

from helpers import STATES


def test_ecos_and_fmpy_agree_to_1e_12(furuta_fmu):
    # a missing engine is a failure here, not a skip: .ci/run installs ecospy and libtbb12
    assert ecos_available() is None, ecos_available()
    start = {"theta1_start": 0.1, "V": 0.0}
    by_fmpy = run_fmpy(furuta_fmu, start, STATES, stop_time=2.0, step=1e-3)
    by_ecos = run_ecos(furuta_fmu, start, STATES, stop_time=2.0, step=1e-3)
    assert by_fmpy.shape == by_ecos.shape == (2000, 5)
    # the pendulum really moved: it falls from 0.1 rad
    assert abs(by_fmpy[-1, 2]) > 1.0
    assert relative_difference(by_ecos, by_fmpy) <= 1e-12
