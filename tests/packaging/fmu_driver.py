"""Run one extracted co-simulation FMU (FMI 2.0 or 3.0) with nothing but the standard library.

A host for tests that must control exactly which Python packages the FMU can import: run
it with the interpreter of a venv (``venv/bin/python -I fmu_driver.py JOB``) and the FMU's
slave sees that venv's packages only (a Python host: the slave runs in this process's
interpreter). fmpy cannot serve there, as it imports numpy itself.

JOB is a JSON file holding one job or a list of jobs (run one after the other in this
process; then a list of results is printed). A job: ``folder`` (the extracted FMU),
``identifier`` (modelIdentifier), ``token`` (GUID / instantiationToken), ``fmi`` (2 or 3),
``start``, ``stop``, ``step``,
``inputs`` (value reference -> ``[[time, value], ...]``, each Real input held from its time
on, set before every step from the last time <= the communication point) and
``outputs`` (Real value references), and optionally ``logging`` (the instance's loggingOn,
default true). Communication points and step sizes are fmpy's
(``start + k * step``, the difference of two as the step) and so are the input settings
(one call for all inputs before every step), so a reference experiment reproduces what
``fmpy.simulate_fmu`` recorded, bit for bit (setting the inputs one call each gave results
1 ulp apart in five of the components). Prints one JSON object: ``rows`` (``[t, outputs...]``
after initialisation and after every step), ``messages`` (the FMU's log, ``[status,
category, message]``) and ``failed`` (the FMI call that returned an error, or null).
"""

import ctypes
import json
import sys
from pathlib import Path

STATUS_ERROR = 3  # fmi2Error / fmi3Error; 4 is Fatal in both


def _drive(job, messages):
    folder = Path(job["folder"]).resolve()
    fmi, ident = job["fmi"], job["identifier"]
    platform = "linux64" if fmi == 2 else "x86_64-linux"
    lib = ctypes.CDLL(str(folder / "binaries" / platform / f"{ident}.so"))
    vr_out = [int(v) for v in job["outputs"]]
    inputs = {int(vr): points for vr, points in job["inputs"].items()}
    Vrs = ctypes.c_uint * max(1, len(vr_out))
    Values = ctypes.c_double * max(1, len(vr_out))
    out_vrs, out_values = Vrs(*vr_out), Values()
    start, stop, step = job["start"], job["stop"], job["step"]
    logging = bool(job.get("logging", True))

    def log(status, category, message):
        messages.append([int(status), (category or b"").decode(errors="replace"),
                         (message or b"").decode(errors="replace")])

    def check(name, status):
        if status >= STATUS_ERROR:
            raise RuntimeError(f"{name} returned status {status}")

    if fmi == 2:
        # fmi2CallbackLogger is variadic: its message is a printf format. On x86-64 the
        # first variadic argument arrives like a sixth fixed one, so it is declared as one
        # and read when the format is "%s" (the bridge's way of passing a message).
        Logger = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int,
                                  ctypes.c_char_p, ctypes.c_char_p, ctypes.c_void_p)

        class Callbacks(ctypes.Structure):
            _fields_ = [("logger", Logger), ("allocateMemory", ctypes.c_void_p),
                        ("freeMemory", ctypes.c_void_p), ("stepFinished", ctypes.c_void_p),
                        ("componentEnvironment", ctypes.c_void_p)]

        libc = ctypes.CDLL(None)
        def log2(env, name, status, category, message, first):
            if message == b"%s" and first:
                message = ctypes.string_at(first)
            log(status, category, message)

        logger = Logger(log2)
        callbacks = Callbacks(logger, ctypes.cast(libc.calloc, ctypes.c_void_p),
                              ctypes.cast(libc.free, ctypes.c_void_p), None, None)
        lib.fmi2Instantiate.restype = ctypes.c_void_p
        lib.fmi2Instantiate.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                                        ctypes.c_char_p, ctypes.POINTER(Callbacks),
                                        ctypes.c_int, ctypes.c_int]
        instance = lib.fmi2Instantiate(b"driver", 1, job["token"].encode(),
                                       (folder / "resources").as_uri().encode(),
                                       ctypes.byref(callbacks), 0, int(logging))
        if not instance:
            raise RuntimeError("fmi2Instantiate returned NULL")
        c = ctypes.c_void_p(instance)
        lib.fmi2SetupExperiment.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_double,
                                            ctypes.c_double, ctypes.c_int, ctypes.c_double]
        check("fmi2SetupExperiment", lib.fmi2SetupExperiment(c, 0, 0.0, start, 1, stop))
        check("fmi2EnterInitializationMode", lib.fmi2EnterInitializationMode(c))

        def set_real(vrs, values):
            check("fmi2SetReal", lib.fmi2SetReal(c, (ctypes.c_uint * len(vrs))(*vrs),
                                                 len(vrs), (ctypes.c_double * len(vrs))(*values)))

        def exit_init():
            check("fmi2ExitInitializationMode", lib.fmi2ExitInitializationMode(c))

        def get_outputs():
            check("fmi2GetReal", lib.fmi2GetReal(c, out_vrs, len(vr_out), out_values))

        lib.fmi2DoStep.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                   ctypes.c_int]

        def do_step(t, h):
            check("fmi2DoStep", lib.fmi2DoStep(c, t, h, 1))

        def finish():
            check("fmi2Terminate", lib.fmi2Terminate(c))
            lib.fmi2FreeInstance(c)
    else:
        Logger = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p,
                                  ctypes.c_char_p)
        logger = Logger(lambda env, status, category, message: log(status, category, message))
        lib.fmi3InstantiateCoSimulation.restype = ctypes.c_void_p
        lib.fmi3InstantiateCoSimulation.argtypes = [
            ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_bool, ctypes.c_bool,
            ctypes.c_bool, ctypes.c_bool, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
            Logger, ctypes.c_void_p]
        instance = lib.fmi3InstantiateCoSimulation(
            b"driver", job["token"].encode(), (str(folder / "resources") + "/").encode(),
            False, logging, False, False, None, 0, None, logger, None)
        if not instance:
            raise RuntimeError("fmi3InstantiateCoSimulation returned NULL")
        c = ctypes.c_void_p(instance)
        lib.fmi3EnterInitializationMode.argtypes = [ctypes.c_void_p, ctypes.c_bool,
                                                    ctypes.c_double, ctypes.c_double,
                                                    ctypes.c_bool, ctypes.c_double]
        check("fmi3EnterInitializationMode",
              lib.fmi3EnterInitializationMode(c, False, 0.0, start, True, stop))

        def set_real(vrs, values):
            check("fmi3SetFloat64", lib.fmi3SetFloat64(
                c, (ctypes.c_uint * len(vrs))(*vrs), ctypes.c_size_t(len(vrs)),
                (ctypes.c_double * len(vrs))(*values), ctypes.c_size_t(len(vrs))))

        def exit_init():
            check("fmi3ExitInitializationMode", lib.fmi3ExitInitializationMode(c))

        def get_outputs():
            check("fmi3GetFloat64", lib.fmi3GetFloat64(
                c, out_vrs, ctypes.c_size_t(len(vr_out)), out_values,
                ctypes.c_size_t(len(vr_out))))

        lib.fmi3DoStep.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                   ctypes.c_bool] + [ctypes.c_void_p] * 4
        flags = [ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool()]
        last = ctypes.c_double()

        def do_step(t, h):
            check("fmi3DoStep", lib.fmi3DoStep(c, t, h, True, *map(ctypes.byref, flags),
                                               ctypes.byref(last)))

        def finish():
            check("fmi3Terminate", lib.fmi3Terminate(c))
            lib.fmi3FreeInstance(c)

    def apply_inputs(t):  # one call for all inputs, in the job's order, as fmpy does
        vrs, values = [], []
        for vr, points in inputs.items():
            held = [value for time, value in points if time <= t]
            if held:
                vrs.append(vr)
                values.append(held[-1])
        if vrs:
            set_real(vrs, values)

    rows = []
    apply_inputs(start)
    exit_init()
    get_outputs()
    rows.append([start, *out_values[:len(vr_out)]])
    n = round((stop - start) / step)
    t = start
    for k in range(n):
        apply_inputs(t)
        after = start + (k + 1) * step  # fmpy's communication points, and its step sizes
        do_step(t, after - t)
        t = after
        get_outputs()
        rows.append([t, *out_values[:len(vr_out)]])
    finish()
    return rows


def main(path):
    jobs = json.loads(Path(path).read_text())
    results = []
    for job in jobs if isinstance(jobs, list) else [jobs]:
        messages, rows, failed = [], [], None
        try:
            rows = _drive(job, messages)
        except RuntimeError as error:
            failed = str(error)
        results.append({"rows": rows, "messages": messages, "failed": failed})
    print(json.dumps(results if isinstance(jobs, list) else results[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
