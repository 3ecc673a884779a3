/*
 * agv-cosim FMU loader: the binary a host loads (binaries/linux64/<model>.so in FMI 2.0,
 * binaries/x86_64-linux/<model>.so in FMI 3.0).
 *
 * The FMU's slave is Python. The bridge that implements the FMI C API over the slave
 * (agv_fmu_bridge.c, shipped beside this library as <model>.bridge.so) uses the Python C
 * API but is not linked against libpython, so that it can use whichever Python the
 * process has. This loader, which uses no Python symbol, makes sure an initialised
 * Python is in the process before it loads the bridge, then forwards every FMI call to
 * it unchanged (one indirect call).
 *
 * Which Python (the first that applies; its version must be the one the bridge was
 * compiled for):
 *  1. a Python already initialised in the process (a Python host such as fmpy, or an
 *     earlier FMU): it is used as it is; the FMU's own packages folder, if it has one
 *     (see 2), is appended to sys.path by the bridge's slave import, after the host's;
 *  2. the FMU's own runtime, binaries/<platform>/python/ (a standalone build: libpython,
 *     the standard library and the packages the FMU needs; see agv_cosim/standalone.py);
 *  3. the interpreter named by the environment variable AGV_COSIM_PYTHON (an executable;
 *     a venv's bin/python gives that venv's site-packages);
 *  4. the interpreter of the active virtual environment, $VIRTUAL_ENV/bin/python3;
 *  5. python3.<minor>, then python3, on PATH.
 * For 3-5 the shared library is <prefix>/lib/<soname> or <prefix>/lib/<multiarch>/<soname>
 * beside the real interpreter (a Python built with --enable-shared, or Debian's
 * libpython3.X package); it is loaded with RTLD_GLOBAL, so the bridge and Python's
 * extension modules (numpy's) see its symbols. The interpreter is started isolated
 * (PYTHONHOME, PYTHONPATH and the user site are ignored) with the chosen executable as
 * its program name, so a venv's pyvenv.cfg and site-packages are found. A failure is
 * reported through the host's logger and instantiation returns NULL; the host process is
 * never ended. The interpreter started here is never finalised (it lives until the
 * process ends), and the bridge is never unloaded while the process runs, so nothing of
 * Python runs from static destructors at exit.
 *
 * It is compiled with the Python headers of the bridge's Python (for the types and the
 * version, PY_MAJOR_VERSION.PY_MINOR_VERSION); no path of the building machine is
 * compiled in.
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
#include <sys/stat.h>
#include <unistd.h>
#include <wchar.h>

#include "fmi2Functions.h"
#include "fmi3FunctionTypes.h"

#define STR_(x) #x
#define STR(x) STR_(x)
#define PY_VERSION_TEXT STR(PY_MAJOR_VERSION) "." STR(PY_MINOR_VERSION)
#define LIBPYTHON_SONAME "libpython" PY_VERSION_TEXT ".so.1.0"
#define PYTHON_VARIABLE "AGV_COSIM_PYTHON"
#define BRIDGE_SUFFIX ".bridge.so"
#define RUNTIME_FOLDER "python"

static const char *const MULTIARCH[] = {"x86_64-linux-gnu", "aarch64-linux-gnu",
                                        "i386-linux-gnu"};

/* ------------------------------------------------------------------ messages */
typedef struct {
    int fmi3;
    const char *instance;
    const fmi2CallbackFunctions *functions2;
    fmi3LogMessageCallback log3;
    fmi3InstanceEnvironment env3;
} Reporter;

static void report(const Reporter *to, int ok, const char *format, ...)
{
    char message[4096];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    if (to->fmi3 && to->log3 != NULL) {
        to->log3(to->env3, ok ? fmi3OK : fmi3Error, ok ? "logStatusOK" : "logStatusError",
                 message);
    } else if (!to->fmi3 && to->functions2 != NULL && to->functions2->logger != NULL) {
        to->functions2->logger(to->functions2->componentEnvironment,
                               to->instance ? to->instance : "", ok ? fmi2OK : fmi2Error,
                               ok ? "logStatusOK" : "logStatusError", "%s", message);
    } else if (!ok) {
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
/* The few Python functions this library calls, looked up at run time (this library is
   not linked against libpython; it uses Python.h for the types only). */
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

static int version_matches(const char *version)
{
    const char *expected = PY_VERSION_TEXT ".";
    return strncmp(version, expected, strlen(expected)) == 0;
}

static int is_file(const char *path)
{
    struct stat info;
    return stat(path, &info) == 0 && S_ISREG(info.st_mode);
}

/* The folder of this library. */
static void own_folder(char *out, size_t size)
{
    char copy[PATH_MAX];
    snprintf(copy, sizeof copy, "%s", own_path());
    snprintf(out, size, "%s", dirname(copy));
}

/* Open the shared library of the Python at `executable` (following links to the real
   interpreter); `tried` collects what was tried. */
static void *open_libpython_of(const char *executable, char *tried, size_t tried_size)
{
    char real[PATH_MAX];
    if (realpath(executable, real) == NULL) return NULL;
    char *bin = dirname(real);
    char candidate[PATH_MAX + 128];
    for (int k = -1; k < (int)(sizeof MULTIARCH / sizeof MULTIARCH[0]); k++) {
        if (k < 0) snprintf(candidate, sizeof candidate, "%s/../lib/%s", bin, LIBPYTHON_SONAME);
        else snprintf(candidate, sizeof candidate, "%s/../lib/%s/%s", bin, MULTIARCH[k],
                      LIBPYTHON_SONAME);
        if (!is_file(candidate)) continue;
        size_t used = strlen(tried);
        snprintf(tried + used, tried_size - used, "%s%s", used ? ", " : "", candidate);
        void *handle = dlopen(candidate, RTLD_NOW | RTLD_GLOBAL);
        if (handle != NULL) return handle;
    }
    return NULL;
}

/* `name` on PATH (an executable file), or 0. */
static int on_path(const char *name, char *out, size_t size)
{
    const char *path = getenv("PATH");
    if (path == NULL) return 0;
    char *copy = strdup(path), *save = NULL;
    int found = 0;
    for (char *dir = strtok_r(copy, ":", &save); dir && !found;
         dir = strtok_r(NULL, ":", &save)) {
        snprintf(out, size, "%s/%s", *dir ? dir : ".", name);
        found = is_file(out) && access(out, X_OK) == 0;
    }
    free(copy);
    return found;
}

typedef struct {
    char executable[PATH_MAX]; /* the program name (empty for the FMU's own runtime) */
    char home[PATH_MAX];       /* PYTHONHOME of the FMU's own runtime (else empty) */
    const char *origin;        /* which rule chose it, for messages */
} Choice;

/* Start the interpreter in `libpython` (just loaded) as `choice` says; 1 on success. */
static int start_python(const Reporter *to, void *libpython, const char *tried,
                        const Choice *choice, int logging_on)
{
    if (!python_lookup(libpython)) {
        report(to, 0, "%s: %s lacks the Python C API", own_path(), tried);
        return 0;
    }
    if (!version_matches(py.Py_GetVersion())) {
        report(to, 0, "%s: %s is Python %.*s, this FMU needs Python %s (%s)", own_path(), tried,
               (int)strcspn(py.Py_GetVersion(), " "), py.Py_GetVersion(), PY_VERSION_TEXT,
               choice->origin);
        return 0;
    }
    if (py.Py_IsInitialized()) return 1;
    PyConfig config;
    py.PyConfig_InitIsolatedConfig(&config);
    PyStatus status = {0};
    if (choice->executable[0]) {
        status = py.PyConfig_SetBytesString(&config, &config.program_name, choice->executable);
    }
    if (!py.PyStatus_Exception(status) && choice->home[0]) {
        status = py.PyConfig_SetBytesString(&config, &config.home, choice->home);
    }
    if (!py.PyStatus_Exception(status)) status = py.Py_InitializeFromConfig(&config);
    py.PyConfig_Clear(&config);
    if (py.PyStatus_Exception(status)) {
        report(to, 0, "%s: cannot start Python from %s (%s): %s%s%s", own_path(), tried,
               choice->origin, status.func ? status.func : "", status.func ? ": " : "",
               status.err_msg ? status.err_msg : "unknown error");
        return 0;
    }
    /* Release the GIL: the bridge takes it on every call. */
    py.PyEval_SaveThread();
    if (logging_on) {
        report(to, 1, "%s: started Python %.*s from %s (%s)", own_path(),
               (int)strcspn(py.Py_GetVersion(), " "), py.Py_GetVersion(), tried, choice->origin);
    }
    return 1;
}

/* Make sure an initialised Python of the right version is in the process; 1 on success. */
static int ensure_python(const Reporter *to, int logging_on)
{
    /* 1. A Python host (fmpy, libcosimpy) or an earlier FMU has one already. */
    if (python_lookup(RTLD_DEFAULT) && py.Py_IsInitialized()) {
        if (!version_matches(py.Py_GetVersion())) {
            report(to, 0, "%s: this process runs Python %.*s; this FMU needs Python %s",
                   own_path(), (int)strcspn(py.Py_GetVersion(), " "), py.Py_GetVersion(),
                   PY_VERSION_TEXT);
            return 0;
        }
        return 1;
    }
    Choice choice = {{0}, {0}, NULL};
    char tried[4 * PATH_MAX] = "";
    void *libpython = NULL;

    /* 2. The FMU's own runtime. */
    char folder[PATH_MAX], library[PATH_MAX + 64];
    own_folder(folder, sizeof folder);
    snprintf(library, sizeof library, "%s/" RUNTIME_FOLDER "/lib/" LIBPYTHON_SONAME, folder);
    if (is_file(library)) {
        snprintf(choice.home, sizeof choice.home, "%s/" RUNTIME_FOLDER, folder);
        choice.origin = "the FMU's own Python runtime";
        snprintf(tried, sizeof tried, "%s", library);
        libpython = dlopen(library, RTLD_NOW | RTLD_GLOBAL);
        if (libpython == NULL) {
            const char *why = dlerror();
            report(to, 0, "%s: cannot load the FMU's own Python library %s: %s", own_path(),
                   library, why ? why : "unknown error");
            return 0;
        }
        return start_python(to, libpython, tried, &choice, logging_on);
    }

    /* 3-5. A Python installed on this machine. */
    const char *named = getenv(PYTHON_VARIABLE);
    const char *venv = getenv("VIRTUAL_ENV");
    if (named && named[0]) {
        snprintf(choice.executable, sizeof choice.executable, "%s", named);
        choice.origin = "named by " PYTHON_VARIABLE;
        if (access(named, X_OK) != 0) {
            report(to, 0, "%s: %s names %s, which is not an executable; set it to a Python %s "
                   "that has the FMU's requirements (resources/requirements.txt)", own_path(),
                   PYTHON_VARIABLE, named, PY_VERSION_TEXT);
            return 0;
        }
    } else if (venv && venv[0] &&
               (snprintf(choice.executable, sizeof choice.executable, "%s/bin/python3", venv),
                access(choice.executable, X_OK) == 0)) {
        choice.origin = "the virtual environment in VIRTUAL_ENV";
    } else if (on_path("python" PY_VERSION_TEXT, choice.executable, sizeof choice.executable)) {
        choice.origin = "python" PY_VERSION_TEXT " on PATH";
    } else if (on_path("python3", choice.executable, sizeof choice.executable)) {
        choice.origin = "python3 on PATH";
    } else {
        report(to, 0, "%s: no Python %s found: this FMU needs one (built with --enable-shared "
               "or with its libpython" PY_VERSION_TEXT " package) that has its requirements "
               "(resources/requirements.txt); name it in %s, activate its venv, or put it "
               "on PATH", own_path(), PY_VERSION_TEXT, PYTHON_VARIABLE);
        return 0;
    }
    libpython = open_libpython_of(choice.executable, tried, sizeof tried);
    if (libpython == NULL) {
        const char *why = tried[0] ? dlerror() : NULL;
        report(to, 0, "%s: cannot load the Python library of %s (%s; tried %s): %s. The FMU "
               "needs a Python %s built with --enable-shared; set %s to one", own_path(),
               choice.executable, choice.origin, tried[0] ? tried : "no " LIBPYTHON_SONAME
               " beside it", why ? why : "not found", PY_VERSION_TEXT, PYTHON_VARIABLE);
        return 0;
    }
    return start_python(to, libpython, tried, &choice, logging_on);
}

/* ------------------------------------------------------------------ the bridge */
#define FMI2_CALLS(X)                                                                    \
    X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetDebugLogging) X(fmi2SetupExperiment)  \
    X(fmi2EnterInitializationMode) X(fmi2ExitInitializationMode) X(fmi2Terminate)         \
    X(fmi2Reset) X(fmi2GetReal) X(fmi2GetInteger) X(fmi2GetBoolean) X(fmi2GetString)      \
    X(fmi2SetReal) X(fmi2SetInteger) X(fmi2SetBoolean) X(fmi2SetString)                   \
    X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate)                             \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate)     \
    X(fmi2GetDirectionalDerivative) X(fmi2SetRealInputDerivatives)                        \
    X(fmi2GetRealOutputDerivatives) X(fmi2DoStep) X(fmi2CancelStep) X(fmi2GetStatus)      \
    X(fmi2GetRealStatus) X(fmi2GetIntegerStatus) X(fmi2GetBooleanStatus)                  \
    X(fmi2GetStringStatus)

#define FMI3_CALLS(X)                                                                    \
    X(fmi3InstantiateCoSimulation) X(fmi3FreeInstance) X(fmi3SetDebugLogging)            \
    X(fmi3EnterInitializationMode) X(fmi3ExitInitializationMode) X(fmi3EnterStepMode)     \
    X(fmi3Terminate) X(fmi3Reset) X(fmi3GetFloat64) X(fmi3SetFloat64) X(fmi3GetInt32)     \
    X(fmi3SetInt32) X(fmi3GetBoolean) X(fmi3SetBoolean) X(fmi3GetString) X(fmi3SetString) \
    X(fmi3GetFMUState) X(fmi3SetFMUState) X(fmi3FreeFMUState)                             \
    X(fmi3SerializedFMUStateSize) X(fmi3SerializeFMUState) X(fmi3DeserializeFMUState)     \
    X(fmi3DoStep)

typedef fmi3Status UnsupportedTYPE(fmi3Instance, const char *);

static struct {
#define FIELD(name) name##TYPE *name;
    FMI2_CALLS(FIELD)
    FMI3_CALLS(FIELD)
#undef FIELD
    UnsupportedTYPE *unsupported3;
} bridge;

static void *bridge_handle = NULL;
static pthread_mutex_t load_lock = PTHREAD_MUTEX_INITIALIZER;

/* Load the bridge (its symbols are looked up with the agv_ prefix); 1 on success. */
static int load_bridge(const Reporter *to, int logging_on)
{
    if (bridge_handle != NULL) return 1;
    char path[PATH_MAX];
    const char *self = own_path();
    size_t length = strlen(self);
    if (length < 3 || strcmp(self + length - 3, ".so") != 0 ||
        length - 3 + sizeof BRIDGE_SUFFIX > sizeof path) {
        report(to, 0, "agv-cosim FMU loader: cannot tell its own path");
        return 0;
    }
    memcpy(path, self, length - 3);
    memcpy(path + length - 3, BRIDGE_SUFFIX, sizeof BRIDGE_SUFFIX);
    if (!is_file(path)) {
        report(to, 0, "%s: the FMU has no %s", self, path);
        return 0;
    }
    if (!ensure_python(to, logging_on)) return 0;
    void *handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (handle == NULL) {
        const char *why = dlerror();
        report(to, 0, "%s: cannot load the bridge %s: %s", self, path, why ? why : "");
        return 0;
    }
#define LOOKUP(name)                                                                     \
    bridge.name = (name##TYPE *)dlsym(handle, "agv_" #name);                              \
    if (bridge.name == NULL) {                                                            \
        report(to, 0, "%s: the bridge %s lacks agv_%s", self, path, #name);                \
        memset(&bridge, 0, sizeof bridge);                                                \
        return 0;                                                                         \
    }
    FMI2_CALLS(LOOKUP)
    FMI3_CALLS(LOOKUP)
#undef LOOKUP
    bridge.unsupported3 = (UnsupportedTYPE *)dlsym(handle, "agv_fmi3Unsupported");
    /* Never unloaded: Python may hold references into it until the process ends. */
    bridge_handle = handle;
    return 1;
}

static int ready(const Reporter *to, int logging_on)
{
    pthread_mutex_lock(&load_lock);
    int ok = load_bridge(to, logging_on);
    pthread_mutex_unlock(&load_lock);
    return ok;
}

/* ------------------------------------------------------------------ FMI 2.0 */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    Reporter to = {0, instanceName, functions, NULL, NULL};
    if (!ready(&to, loggingOn)) return NULL;
    return bridge.fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation,
                                  functions, visible, loggingOn);
}

void fmi2FreeInstance(fmi2Component c)
{
    if (c != NULL && bridge.fmi2FreeInstance != NULL) bridge.fmi2FreeInstance(c);
}

/* Every other call goes to the bridge unchanged; an instance exists only once it is
   loaded, so the table is filled whenever a host has an instance to pass. */
#define FORWARD2(name, params, args)                                                     \
    fmi2Status name params                                                                \
    {                                                                                     \
        if (c == NULL || bridge.name == NULL) return fmi2Error;                           \
        return bridge.name args;                                                          \
    }

typedef const fmi2ValueReference *VRs;
FORWARD2(fmi2SetDebugLogging,
         (fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]), (c, on, n, cat))
FORWARD2(fmi2SetupExperiment,
         (fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
          fmi2Boolean stopDef, fmi2Real stop),
         (c, tolDef, tol, start, stopDef, stop))
FORWARD2(fmi2EnterInitializationMode, (fmi2Component c), (c))
FORWARD2(fmi2ExitInitializationMode, (fmi2Component c), (c))
FORWARD2(fmi2Terminate, (fmi2Component c), (c))
FORWARD2(fmi2Reset, (fmi2Component c), (c))
FORWARD2(fmi2GetReal, (fmi2Component c, VRs vr, size_t n, fmi2Real v[]), (c, vr, n, v))
FORWARD2(fmi2GetInteger, (fmi2Component c, VRs vr, size_t n, fmi2Integer v[]), (c, vr, n, v))
FORWARD2(fmi2GetBoolean, (fmi2Component c, VRs vr, size_t n, fmi2Boolean v[]), (c, vr, n, v))
FORWARD2(fmi2GetString, (fmi2Component c, VRs vr, size_t n, fmi2String v[]), (c, vr, n, v))
FORWARD2(fmi2SetReal, (fmi2Component c, VRs vr, size_t n, const fmi2Real v[]), (c, vr, n, v))
FORWARD2(fmi2SetInteger, (fmi2Component c, VRs vr, size_t n, const fmi2Integer v[]),
         (c, vr, n, v))
FORWARD2(fmi2SetBoolean, (fmi2Component c, VRs vr, size_t n, const fmi2Boolean v[]),
         (c, vr, n, v))
FORWARD2(fmi2SetString, (fmi2Component c, VRs vr, size_t n, const fmi2String v[]),
         (c, vr, n, v))
FORWARD2(fmi2GetFMUstate, (fmi2Component c, fmi2FMUstate *s), (c, s))
FORWARD2(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate s), (c, s))
FORWARD2(fmi2FreeFMUstate, (fmi2Component c, fmi2FMUstate *s), (c, s))
FORWARD2(fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate s, size_t *size),
         (c, s, size))
FORWARD2(fmi2SerializeFMUstate,
         (fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size), (c, s, b, size))
FORWARD2(fmi2DeSerializeFMUstate,
         (fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s), (c, b, size, s))
FORWARD2(fmi2GetDirectionalDerivative,
         (fmi2Component c, VRs vu, size_t nu, VRs vk, size_t nk, const fmi2Real dk[],
          fmi2Real dv[]),
         (c, vu, nu, vk, nk, dk, dv))
FORWARD2(fmi2SetRealInputDerivatives,
         (fmi2Component c, VRs vr, size_t n, const fmi2Integer order[], const fmi2Real v[]),
         (c, vr, n, order, v))
FORWARD2(fmi2GetRealOutputDerivatives,
         (fmi2Component c, VRs vr, size_t n, const fmi2Integer order[], fmi2Real v[]),
         (c, vr, n, order, v))
FORWARD2(fmi2DoStep, (fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior),
         (c, t, h, noSetPrior))
FORWARD2(fmi2CancelStep, (fmi2Component c), (c))
FORWARD2(fmi2GetStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Status *v), (c, s, v))
FORWARD2(fmi2GetRealStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Real *v), (c, s, v))
FORWARD2(fmi2GetIntegerStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Integer *v),
         (c, s, v))
FORWARD2(fmi2GetBooleanStatus, (fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v),
         (c, s, v))
FORWARD2(fmi2GetStringStatus, (fmi2Component c, const fmi2StatusKind s, fmi2String *v),
         (c, s, v))

/* ------------------------------------------------------------------ FMI 3.0 */
const char *fmi3GetVersion(void) { return "3.0"; }

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Reporter to = {1, instanceName, NULL, logMessage, instanceEnvironment};
    if (!ready(&to, loggingOn)) return NULL;
    return bridge.fmi3InstantiateCoSimulation(
        instanceName, instantiationToken, resourcePath, visible, loggingOn, eventModeUsed,
        earlyReturnAllowed, requiredIntermediateVariables, nRequiredIntermediateVariables,
        instanceEnvironment, logMessage, intermediateUpdate);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName,
                                          fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    Reporter to = {1, instanceName, NULL, logMessage, instanceEnvironment};
    report(&to, 0, "%s: this FMU supports co-simulation only", own_path());
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, void *clockUpdate, void *lockPreemption,
    void *unlockPreemption)
{
    (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    Reporter to = {1, instanceName, NULL, logMessage, instanceEnvironment};
    report(&to, 0, "%s: this FMU supports co-simulation only", own_path());
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance)
{
    if (instance != NULL && bridge.fmi3FreeInstance != NULL) bridge.fmi3FreeInstance(instance);
}

#define FORWARD3(name, params, args)                                                     \
    fmi3Status name params                                                                \
    {                                                                                     \
        if (instance == NULL || bridge.name == NULL) return fmi3Error;                    \
        return bridge.name args;                                                          \
    }

typedef const fmi3ValueReference *VR3;
FORWARD3(fmi3SetDebugLogging,
         (fmi3Instance instance, fmi3Boolean on, size_t n, const fmi3String cat[]),
         (instance, on, n, cat))
FORWARD3(fmi3EnterInitializationMode,
         (fmi3Instance instance, fmi3Boolean tolDef, fmi3Float64 tol, fmi3Float64 start,
          fmi3Boolean stopDef, fmi3Float64 stop),
         (instance, tolDef, tol, start, stopDef, stop))
FORWARD3(fmi3ExitInitializationMode, (fmi3Instance instance), (instance))
FORWARD3(fmi3EnterStepMode, (fmi3Instance instance), (instance))
FORWARD3(fmi3Terminate, (fmi3Instance instance), (instance))
FORWARD3(fmi3Reset, (fmi3Instance instance), (instance))
FORWARD3(fmi3GetFloat64, (fmi3Instance instance, VR3 vr, size_t n, fmi3Float64 v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3SetFloat64,
         (fmi3Instance instance, VR3 vr, size_t n, const fmi3Float64 v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3GetInt32, (fmi3Instance instance, VR3 vr, size_t n, fmi3Int32 v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3SetInt32, (fmi3Instance instance, VR3 vr, size_t n, const fmi3Int32 v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3GetBoolean, (fmi3Instance instance, VR3 vr, size_t n, fmi3Boolean v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3SetBoolean,
         (fmi3Instance instance, VR3 vr, size_t n, const fmi3Boolean v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3GetString, (fmi3Instance instance, VR3 vr, size_t n, fmi3String v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3SetString, (fmi3Instance instance, VR3 vr, size_t n, const fmi3String v[], size_t m),
         (instance, vr, n, v, m))
FORWARD3(fmi3GetFMUState, (fmi3Instance instance, fmi3FMUState *s), (instance, s))
FORWARD3(fmi3SetFMUState, (fmi3Instance instance, fmi3FMUState s), (instance, s))
FORWARD3(fmi3FreeFMUState, (fmi3Instance instance, fmi3FMUState *s), (instance, s))
FORWARD3(fmi3SerializedFMUStateSize, (fmi3Instance instance, fmi3FMUState s, size_t *size),
         (instance, s, size))
FORWARD3(fmi3SerializeFMUState,
         (fmi3Instance instance, fmi3FMUState s, fmi3Byte b[], size_t size),
         (instance, s, b, size))
FORWARD3(fmi3DeserializeFMUState,
         (fmi3Instance instance, const fmi3Byte b[], size_t size, fmi3FMUState *s),
         (instance, b, size, s))
FORWARD3(fmi3DoStep,
         (fmi3Instance instance, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetPrior,
          fmi3Boolean *event, fmi3Boolean *terminate, fmi3Boolean *early, fmi3Float64 *last),
         (instance, t, h, noSetPrior, event, terminate, early, last))

/* The FMI 3.0 functions this FMU does not support: each reports itself through the
   instance's logger and returns fmi3Error. They take the instance as their first argument
   like every FMI 3.0 function; the others are not read (the x86-64 and AArch64 calling
   conventions let a function ignore trailing arguments). */
#define UNSUPPORTED3(name)                                                               \
    fmi3Status name(fmi3Instance instance)                                                \
    {                                                                                     \
        if (instance == NULL || bridge.unsupported3 == NULL) return fmi3Error;            \
        return bridge.unsupported3(instance, #name);                                      \
    }
UNSUPPORTED3(fmi3EnterEventMode)
UNSUPPORTED3(fmi3GetFloat32) UNSUPPORTED3(fmi3SetFloat32)
UNSUPPORTED3(fmi3GetInt8) UNSUPPORTED3(fmi3SetInt8)
UNSUPPORTED3(fmi3GetUInt8) UNSUPPORTED3(fmi3SetUInt8)
UNSUPPORTED3(fmi3GetInt16) UNSUPPORTED3(fmi3SetInt16)
UNSUPPORTED3(fmi3GetUInt16) UNSUPPORTED3(fmi3SetUInt16)
UNSUPPORTED3(fmi3GetUInt32) UNSUPPORTED3(fmi3SetUInt32)
UNSUPPORTED3(fmi3GetInt64) UNSUPPORTED3(fmi3SetInt64)
UNSUPPORTED3(fmi3GetUInt64) UNSUPPORTED3(fmi3SetUInt64)
UNSUPPORTED3(fmi3GetBinary) UNSUPPORTED3(fmi3SetBinary)
UNSUPPORTED3(fmi3GetClock) UNSUPPORTED3(fmi3SetClock)
UNSUPPORTED3(fmi3GetNumberOfVariableDependencies) UNSUPPORTED3(fmi3GetVariableDependencies)
UNSUPPORTED3(fmi3GetDirectionalDerivative) UNSUPPORTED3(fmi3GetAdjointDerivative)
UNSUPPORTED3(fmi3EnterConfigurationMode) UNSUPPORTED3(fmi3ExitConfigurationMode)
UNSUPPORTED3(fmi3GetIntervalDecimal) UNSUPPORTED3(fmi3GetIntervalFraction)
UNSUPPORTED3(fmi3GetShiftDecimal) UNSUPPORTED3(fmi3GetShiftFraction)
UNSUPPORTED3(fmi3SetIntervalDecimal) UNSUPPORTED3(fmi3SetIntervalFraction)
UNSUPPORTED3(fmi3SetShiftDecimal) UNSUPPORTED3(fmi3SetShiftFraction)
UNSUPPORTED3(fmi3EvaluateDiscreteStates) UNSUPPORTED3(fmi3UpdateDiscreteStates)
UNSUPPORTED3(fmi3EnterContinuousTimeMode) UNSUPPORTED3(fmi3CompletedIntegratorStep)
UNSUPPORTED3(fmi3SetTime) UNSUPPORTED3(fmi3SetContinuousStates)
UNSUPPORTED3(fmi3GetContinuousStateDerivatives) UNSUPPORTED3(fmi3GetEventIndicators)
UNSUPPORTED3(fmi3GetContinuousStates) UNSUPPORTED3(fmi3GetNominalsOfContinuousStates)
UNSUPPORTED3(fmi3GetNumberOfEventIndicators) UNSUPPORTED3(fmi3GetNumberOfContinuousStates)
UNSUPPORTED3(fmi3GetOutputDerivatives) UNSUPPORTED3(fmi3ActivateModelPartition)
