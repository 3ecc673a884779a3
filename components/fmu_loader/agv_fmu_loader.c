/*
 * agv-cosim FMU loader: the binary a host loads as binaries/linux64/<modelIdentifier>.so.
 *
 * pythonfmu's wrapper library (shipped beside this one as <modelIdentifier>.pythonfmu.so)
 * runs the slave in an embedded Python, but it is not linked against libpython and relies
 * on the host process to have one. This loader makes any FMI 2.0 host work:
 *
 *  1. On the first fmi2Instantiate it looks for a Python already in the process (a Python
 *     host such as fmpy). Only if there is none it loads libpython with RTLD_GLOBAL (so
 *     that the wrapper and Python's extension modules such as numpy's see its symbols)
 *     and starts an isolated interpreter on the Python this FMU was built with, or on the
 *     one named by the environment variable AGV_COSIM_PYTHON. Failure is reported through
 *     the host's logger with fmi2Error and fmi2Instantiate returns NULL; the host process
 *     is never ended.
 *  2. It then loads the wrapper library and forwards every FMI 2.0 co-simulation call to
 *     it unchanged.
 *  3. Clean unloading: pythonfmu 0.7 keeps its interpreter state in a global C++
 *     shared_ptr and resets it again from an unload hook that runs after C++ static
 *     destruction has already destroyed it (a double release at process exit). An exit
 *     handler registered here after the wrapper is loaded runs before the wrapper's
 *     static destructors: it resets the shared_ptr through the wrapper's own
 *     finalizePythonInterpreter() while it is alive and unloads the wrapper, so the
 *     later reset finds an empty pointer. The same handler runs when a host unloads this
 *     library (dlclose).
 *
 * Build-time constants (the build passes them with -D): AGV_PYTHON_EXECUTABLE (the
 * interpreter, e.g. a venv's bin/python), AGV_LIBPYTHON (its shared library) and
 * AGV_LIBPYTHON_SONAME (e.g. libpython3.11.so.1.0), AGV_MULTIARCH (Debian's library
 * subfolder, e.g. x86_64-linux-gnu). The Python headers are the ones of
 * that interpreter: the loader only starts a Python of the same major.minor version.
 */
#define _GNU_SOURCE
#include <Python.h>

#include <dlfcn.h>
#include <libgen.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fmi2Functions.h"

#ifndef AGV_PYTHON_EXECUTABLE
#error "AGV_PYTHON_EXECUTABLE must be defined by the build"
#endif
#ifndef AGV_LIBPYTHON
#error "AGV_LIBPYTHON must be defined by the build"
#endif
#ifndef AGV_LIBPYTHON_SONAME
#error "AGV_LIBPYTHON_SONAME must be defined by the build"
#endif
#ifndef AGV_MULTIARCH
#define AGV_MULTIARCH "x86_64-linux-gnu"
#endif

#define PYTHON_VARIABLE "AGV_COSIM_PYTHON"
#define WRAPPER_SUFFIX ".pythonfmu.so"

/* ------------------------------------------------------------------ wrapper table */
#define FORWARDED(X)                                                                     \
    X(fmi2SetDebugLogging) X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetupExperiment)  \
    X(fmi2EnterInitializationMode) X(fmi2ExitInitializationMode) X(fmi2Terminate)         \
    X(fmi2Reset) X(fmi2GetReal) X(fmi2GetInteger) X(fmi2GetBoolean) X(fmi2GetString)      \
    X(fmi2SetReal) X(fmi2SetInteger) X(fmi2SetBoolean) X(fmi2SetString)                   \
    X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate)                             \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate)     \
    X(fmi2GetDirectionalDerivative) X(fmi2SetRealInputDerivatives)                        \
    X(fmi2GetRealOutputDerivatives) X(fmi2DoStep) X(fmi2CancelStep) X(fmi2GetStatus)      \
    X(fmi2GetRealStatus) X(fmi2GetIntegerStatus) X(fmi2GetBooleanStatus)                  \
    X(fmi2GetStringStatus)

static struct {
#define FIELD(name) name##TYPE *name;
    FORWARDED(FIELD)
#undef FIELD
    void (*finalize)(void);
} wrapper;

static void *wrapper_handle = NULL;
static pthread_mutex_t load_lock = PTHREAD_MUTEX_INITIALIZER;

/* ------------------------------------------------------------------ messages */
static void report(const fmi2CallbackFunctions *functions, fmi2String instanceName,
                   const char *format, ...)
{
    char message[2048];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    if (functions != NULL && functions->logger != NULL) {
        functions->logger(functions->componentEnvironment,
                          instanceName ? instanceName : "", fmi2Error, "logError",
                          "%s", message);
    } else {
        fprintf(stderr, "%s\n", message);
    }
}

static const char *own_path(void)
{
    static char path[PATH_MAX];
    Dl_info info;
    if (path[0] == '\0' && dladdr((void *)&own_path, &info) && info.dli_fname) {
        snprintf(path, sizeof path, "%s", info.dli_fname);
    }
    return path;
}

/* ------------------------------------------------------------------ Python */
/* Python functions, looked up at run time: this library is not linked against libpython. */
#define PYTHON_API(X)                                                                    \
    X(Py_IsInitialized) X(Py_GetVersion) X(PyConfig_InitIsolatedConfig)                   \
    X(PyConfig_SetBytesString) X(PyConfig_Clear) X(Py_InitializeFromConfig)               \
    X(PyStatus_Exception) X(PyEval_SaveThread)

static struct {
#define FIELD(name) __typeof__(&name) name;
    PYTHON_API(FIELD)
#undef FIELD
} py;

static int python_lookup(void *handle)
{
#define LOOKUP(name)                                                                     \
    py.name = (__typeof__(&name))dlsym(handle, #name);                                    \
    if (py.name == NULL) return 0;
    PYTHON_API(LOOKUP)
#undef LOOKUP
    return 1;
}

/* The shared library of the Python at `executable`: <prefix>/lib[/<multiarch>]/<soname>
   beside the real interpreter (a venv's bin/python links to it). */
static void *open_libpython_of(const char *executable, char *tried, size_t tried_size)
{
    char real[PATH_MAX];
    if (realpath(executable, real) == NULL) return NULL;
    char *bin = dirname(real);
    const char *layouts[] = {"%s/../lib/%s", "%s/../lib/" AGV_MULTIARCH "/%s"};
    for (size_t k = 0; k < sizeof layouts / sizeof layouts[0]; k++) {
        char candidate[PATH_MAX + 64];
        snprintf(candidate, sizeof candidate, layouts[k], bin, AGV_LIBPYTHON_SONAME);
        size_t used = strlen(tried);
        snprintf(tried + used, tried_size - used, "%s%s", used ? ", " : "", candidate);
        void *handle = dlopen(candidate, RTLD_NOW | RTLD_GLOBAL);
        if (handle != NULL) {
            snprintf(tried, tried_size, "%s", candidate);
            return handle;
        }
    }
    return NULL;
}

/* Make sure an initialised Python is in the process; 1 on success. */
static int ensure_python(const fmi2CallbackFunctions *functions, fmi2String instanceName,
                         fmi2Boolean loggingOn)
{
    /* A Python host (fmpy, libcosimpy) or an earlier FMU has one already. */
    if (python_lookup(RTLD_DEFAULT) && py.Py_IsInitialized()) {
        return 1;
    }
    const char *chosen = getenv(PYTHON_VARIABLE);
    const char *executable = (chosen && chosen[0]) ? chosen : AGV_PYTHON_EXECUTABLE;
    const char *origin = (chosen && chosen[0]) ? "named by " PYTHON_VARIABLE
                                               : "this FMU was built with";
    if (access(executable, X_OK) != 0) {
        report(functions, instanceName,
               "%s: the Python %s (%s) is not there or not executable; install it, or set %s "
               "to a Python %d.%d "
               "executable that has numpy and scipy",
               own_path(), origin, executable, PYTHON_VARIABLE, PY_MAJOR_VERSION,
               PY_MINOR_VERSION);
        return 0;
    }
    void *libpython;
    char tried[3 * PATH_MAX] = "";
    if (chosen && chosen[0]) {
        libpython = open_libpython_of(executable, tried, sizeof tried);
    } else {
        libpython = dlopen(AGV_LIBPYTHON, RTLD_NOW | RTLD_GLOBAL);
        snprintf(tried, sizeof tried, "%s", AGV_LIBPYTHON);
        if (libpython == NULL) libpython = open_libpython_of(executable, tried, sizeof tried);
    }
    if (libpython == NULL) {
        const char *why = dlerror();
        report(functions, instanceName,
               "%s: cannot load the Python library for %s (tried %s): %s. The FMU needs a "
               "Python %d.%d built with --enable-shared; set %s to one",
               own_path(), executable, tried, why ? why : "not found", PY_MAJOR_VERSION,
               PY_MINOR_VERSION, PYTHON_VARIABLE);
        return 0;
    }
    if (!python_lookup(libpython)) {
        report(functions, instanceName, "%s: %s lacks the Python C API", own_path(), tried);
        return 0;
    }
    if (py.Py_IsInitialized()) {
        return 1;
    }
    char expected[16];
    snprintf(expected, sizeof expected, "%d.%d.", PY_MAJOR_VERSION, PY_MINOR_VERSION);
    if (strncmp(py.Py_GetVersion(), expected, strlen(expected)) != 0) {
        report(functions, instanceName,
               "%s: %s is Python %.*s, this FMU needs Python %d.%d", own_path(), tried,
               (int)strcspn(py.Py_GetVersion(), " "), py.Py_GetVersion(), PY_MAJOR_VERSION,
               PY_MINOR_VERSION);
        return 0;
    }
    /* Isolated: PYTHONHOME, PYTHONPATH and the user site of the host's environment are
       ignored. The program name makes Python find a venv's pyvenv.cfg and site-packages. */
    PyConfig config;
    py.PyConfig_InitIsolatedConfig(&config);
    PyStatus status = py.PyConfig_SetBytesString(&config, &config.program_name, executable);
    if (!py.PyStatus_Exception(status)) {
        status = py.Py_InitializeFromConfig(&config);
    }
    py.PyConfig_Clear(&config);
    if (py.PyStatus_Exception(status)) {
        report(functions, instanceName, "%s: cannot start Python %s: %s%s%s", own_path(),
               executable, status.func ? status.func : "", status.func ? ": " : "",
               status.err_msg ? status.err_msg : "unknown error");
        return 0;
    }
    /* Release the GIL: the wrapper takes it with PyGILState_Ensure on every call. */
    py.PyEval_SaveThread();
    if (loggingOn && functions != NULL && functions->logger != NULL) {
        functions->logger(functions->componentEnvironment, instanceName ? instanceName : "",
                          fmi2OK, "logStatusOK", "%s: started Python %.*s (%s, %s)",
                          own_path(), (int)strcspn(py.Py_GetVersion(), " "),
                          py.Py_GetVersion(), executable, tried);
    }
    return 1;
}

/* ------------------------------------------------------------------ wrapper */
static void unload_wrapper(void)
{
    pthread_mutex_lock(&load_lock);
    if (wrapper_handle != NULL) {
        if (wrapper.finalize != NULL) wrapper.finalize();
        dlclose(wrapper_handle);
        wrapper_handle = NULL;
        memset(&wrapper, 0, sizeof wrapper);
    }
    pthread_mutex_unlock(&load_lock);
}

static int load_wrapper(const fmi2CallbackFunctions *functions, fmi2String instanceName)
{
    char path[PATH_MAX];
    const char *self = own_path();
    size_t length = strlen(self);
    if (length < 3 || strcmp(self + length - 3, ".so") != 0 ||
        length - 3 + sizeof WRAPPER_SUFFIX > sizeof path) {
        report(functions, instanceName, "agv-cosim FMU loader: cannot tell its own path");
        return 0;
    }
    memcpy(path, self, length - 3);
    memcpy(path + length - 3, WRAPPER_SUFFIX, sizeof WRAPPER_SUFFIX);
    void *handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (handle == NULL) {
        report(functions, instanceName, "%s: cannot load the pythonfmu wrapper: %s", self,
               dlerror());
        return 0;
    }
#define LOOKUP(name)                                                                     \
    wrapper.name = (name##TYPE *)dlsym(handle, #name);                                    \
    if (wrapper.name == NULL) {                                                           \
        report(functions, instanceName, "%s: the wrapper %s lacks %s", self, path, #name); \
        dlclose(handle);                                                                  \
        memset(&wrapper, 0, sizeof wrapper);                                              \
        return 0;                                                                         \
    }
    FORWARDED(LOOKUP)
#undef LOOKUP
    wrapper.finalize = (void (*)(void))dlsym(handle, "finalizePythonInterpreter");
    wrapper_handle = handle;
    /* Registered after the wrapper's static constructors ran, so it runs before its
       static destructors, at exit() as well as when this library is unloaded. */
    atexit(unload_wrapper);
    return 1;
}

/* ------------------------------------------------------------------ FMI 2.0 */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    pthread_mutex_lock(&load_lock);
    int ready = wrapper_handle != NULL ||
                (ensure_python(functions, instanceName, loggingOn) &&
                  load_wrapper(functions, instanceName));
    pthread_mutex_unlock(&load_lock);
    if (!ready) return NULL;
    return wrapper.fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation,
                                   functions, visible, loggingOn);
}

void fmi2FreeInstance(fmi2Component c)
{
    if (c != NULL && wrapper.fmi2FreeInstance != NULL) wrapper.fmi2FreeInstance(c);
}

/* Every other call goes to the wrapper unchanged; an instance exists only once it is
   loaded, so the table is filled whenever a host has a component to pass. */
#define FORWARD(name, params, args)                                                      \
    fmi2Status name params                                                                \
    {                                                                                     \
        if (wrapper.name == NULL) return fmi2Error;                                       \
        return wrapper.name args;                                                         \
    }

typedef const fmi2ValueReference *VRs;
FORWARD(fmi2SetDebugLogging, (fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]),
        (c, on, n, cat))
FORWARD(fmi2SetupExperiment,
        (fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start, fmi2Boolean stopDef,
         fmi2Real stop),
        (c, tolDef, tol, start, stopDef, stop))
FORWARD(fmi2EnterInitializationMode, (fmi2Component c), (c))
FORWARD(fmi2ExitInitializationMode, (fmi2Component c), (c))
FORWARD(fmi2Terminate, (fmi2Component c), (c))
FORWARD(fmi2Reset, (fmi2Component c), (c))
FORWARD(fmi2GetReal, (fmi2Component c, VRs vr, size_t n, fmi2Real v[]), (c, vr, n, v))
FORWARD(fmi2GetInteger, (fmi2Component c, VRs vr, size_t n, fmi2Integer v[]), (c, vr, n, v))
FORWARD(fmi2GetBoolean, (fmi2Component c, VRs vr, size_t n, fmi2Boolean v[]), (c, vr, n, v))
FORWARD(fmi2GetString, (fmi2Component c, VRs vr, size_t n, fmi2String v[]), (c, vr, n, v))
FORWARD(fmi2SetReal, (fmi2Component c, VRs vr, size_t n, const fmi2Real v[]), (c, vr, n, v))
FORWARD(fmi2SetInteger, (fmi2Component c, VRs vr, size_t n, const fmi2Integer v[]),
        (c, vr, n, v))
FORWARD(fmi2SetBoolean, (fmi2Component c, VRs vr, size_t n, const fmi2Boolean v[]),
        (c, vr, n, v))
FORWARD(fmi2SetString, (fmi2Component c, VRs vr, size_t n, const fmi2String v[]), (c, vr, n, v))
FORWARD(fmi2GetFMUstate, (fmi2Component c, fmi2FMUstate *s), (c, s))
FORWARD(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate s), (c, s))
FORWARD(fmi2FreeFMUstate, (fmi2Component c, fmi2FMUstate *s), (c, s))
FORWARD(fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate s, size_t *size),
        (c, s, size))
FORWARD(fmi2SerializeFMUstate, (fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size),
        (c, s, b, size))
FORWARD(fmi2DeSerializeFMUstate,
        (fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s), (c, b, size, s))
FORWARD(fmi2GetDirectionalDerivative,
        (fmi2Component c, VRs vu, size_t nu, VRs vk, size_t nk, const fmi2Real dk[],
         fmi2Real dv[]),
        (c, vu, nu, vk, nk, dk, dv))
FORWARD(fmi2SetRealInputDerivatives,
        (fmi2Component c, VRs vr, size_t n, const fmi2Integer order[], const fmi2Real v[]),
        (c, vr, n, order, v))
FORWARD(fmi2GetRealOutputDerivatives,
        (fmi2Component c, VRs vr, size_t n, const fmi2Integer order[], fmi2Real v[]),
        (c, vr, n, order, v))
FORWARD(fmi2DoStep,
        (fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior), (c, t, h, noSetPrior))
FORWARD(fmi2CancelStep, (fmi2Component c), (c))
FORWARD(fmi2GetStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Status *v), (c, s, v))
FORWARD(fmi2GetRealStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Real *v), (c, s, v))
FORWARD(fmi2GetIntegerStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Integer *v),
        (c, s, v))
FORWARD(fmi2GetBooleanStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v),
        (c, s, v))
FORWARD(fmi2GetStringStatus, (fmi2Component c, const fmi2StatusKind s, fmi2String *v),
        (c, s, v))
