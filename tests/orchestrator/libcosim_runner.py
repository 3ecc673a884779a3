"""Run an SSP package in libcosim (libcosimpy): the third-party master the tests compare
our orchestrator with (tests/orchestrator/ssp/test_ssp.py). Not part of agv_cosim: users run
SSP packages with ``agv-cosim run PACKAGE.ssp``; libcosim is only a cross-check, and
libcosimpy is a test dependency.
"""

import tempfile
from decimal import Decimal

from agv_cosim.ssp.importer import load_ssp


def run_libcosim(ssp_path, variables, step=None, stop=None, start=0.0):
    """Run an SSP package in libcosim (libcosimpy) and return recorded time series.

    Parameters
    ----------
    ssp_path : path
        The ``.ssp`` package.
    variables : list of str
        ``component.variable`` Real variables to record.
    step, stop : float, optional
        Macro step and stop time [s] (default: read from the package's SSD).
    start : float
        Start time [s] of the package (libcosim reads it from the SSD; used here only to
        turn step numbers into times).

    Returns
    -------
    (numpy.ndarray, dict of str -> numpy.ndarray)
        Times [s] t_k = start + k step for k = 0 ... n and the values libcosim observed
        at them (after the step that ended at t_k; k = 0 after initialisation).
    """
    import numpy as np
    from libcosimpy import _internal
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    if step is None or stop is None:
        with tempfile.TemporaryDirectory() as work:
            manifest = load_ssp(ssp_path, work)
        step = manifest.step if step is None else step
        stop = manifest.stop if stop is None else stop
        start = manifest.start
    step_ns = int(round(step * 1e9))
    n_steps = int(round((stop - start) / step))
    log_output_level(CosimLogLevel.WARNING)
    try:
        execution = CosimExecution.from_ssp_file(str(ssp_path), step_size=step_ns)
    except AssertionError:
        raise RuntimeError(f"libcosim: {_internal.get_last_error_message()}") from None
    observer = CosimObserver.create_time_series(buffer_size=n_steps + 2)
    execution.add_observer(observer)
    infos = {}
    for item in variables:
        cname, vname = item.split(".")
        index = execution.slave_index_from_instance_name(cname)
        if cname not in infos:
            infos[cname] = {v.name.decode(): v.reference
                            for v in execution.slave_variables(index)}
        ref = infos[cname][vname]
        observer.start_time_series(index, ref, CosimVariableType.REAL)
        infos.setdefault("_refs", {})[item] = (index, ref)
    if not execution.step(n_steps):
        raise RuntimeError(f"libcosim: {_internal.get_last_error_message()}")
    series = {}
    # the communication points t_k = start + k step, each the double nearest to the
    # exact decimal (libcosim counts integer nanoseconds; our master's grid is the same)
    times = np.array([float(Decimal(repr(start)) + k * Decimal(repr(step)))
                      for k in range(n_steps + 1)])
    for item in variables:
        index, ref = infos["_refs"][item]
        # libcosimpy trims its result by counting step numbers equal to 0 (taken as empty
        # slots), so a request that includes step 0 loses its newest sample: read step 0
        # (with one sample more, then trimmed back to one) and steps 1.. separately
        column = np.full(n_steps + 1, np.nan)
        for first, count in ((0, 2), (1, n_steps)):
            _, steps, values = observer.time_series_real_samples(index, ref, from_step=first,
                                                                 sample_count=count)
            steps = np.asarray(steps, dtype=int)
            keep = steps <= n_steps if first else steps == 0
            column[steps[keep]] = np.asarray(values)[keep]
        if np.isnan(column).any():
            missing = int(np.flatnonzero(np.isnan(column))[0])
            raise RuntimeError(f"libcosim: no sample of {item} at step {missing}")
        series[item] = column
    return times, series
