/*
 * agv-cosim FMU bridge: the FMI 2.0 and FMI 3.0 co-simulation C API over a Python slave.
 *
 * The slave is a pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0) slave class: this library
 * takes the place of those packages' C++ wrappers at run time (they still write the model
 * description at build time). It is loaded by the FMU loader (agv_fmu_loader.c), which has
 * made sure that an initialised Python is in the process before, so this library may
 * leave the Python C API's symbols undefined: they resolve against the libpython the
 * loader opened with RTLD_GLOBAL, or the host's own Python.
 *
 * Every exported function carries the prefix agv_ (agv_fmi2DoStep, agv_fmi3DoStep, ...):
 * the loader looks them up by those names and forwards the host's calls unchanged.
 *
 * What it does per instance:
 *  - instantiation: puts the FMU's resources folder first on sys.path (and a standalone
 *    FMU's packages last, if the interpreter is not the FMU's own), imports the slave
 *    module named in resources/slavemodule.txt (re-executing it if an earlier instance
 *    imported it, so that it binds to this FMU's files), takes the one class the module
 *    defines that has a do_step method, and creates the slave with the keyword arguments
 *    instance_name, resources and visible. Its bound methods are looked up once.
 *  - every call: takes the GIL (on a host's own threads through one thread state per
 *    thread, kept while instances use it: see "the GIL on any thread"), calls the
 *    slave method with the values as Python lists
 *    (value references as a cached tuple), passes messages the slave queued in its
 *    log_queue to the host's logger (only when there are any), releases the GIL. A Python
 *    exception is logged (its type and message) and the call returns fmi2Fatal /
 *    fmi3Fatal, as pythonfmu does.
 *  - Real / Float64 values: a slave whose _fmi_real_access() returns (names, quiet), not
 *    None, is
 *    read and written without a Python call per value: names maps value references to
 *    the attributes that hold the values as floats, quiet lists the inputs no output
 *    depends on directly. Before a read, without a core the slave's _fresh_outputs() is
 *    called, else with _stale true its publish() (errors to its _outputs_failed) and
 *    _stale is set false; after a write of an input not in quiet, _stale is set true. That is the contract of agv_core.fmi.slave_base.SlaveLogic, whose
 *    get_real / set_real do the same in Python; any value reference not in names takes
 *    the slave's own get/set method.
 *  - stepping: a slave whose _fmi_step_access() is true is stepped the way its do_step
 *    would (advance, time, publish or a lazy mark; see SlaveLogic._fmi_step_access)
 *    without the call of do_step itself; errors go to its _step_failed.
 *  - FMU state: the object _get_fmu_state() returns is the FMUstate (a reference held by
 *    the host until it frees it); serialisation uses the class's _fmu_state_to_bytes /
 *    _fmu_state_from_bytes.
 *  - fmi2DoStep: a false result of do_step is fmi2Discard with fmi2Terminated true and
 *    fmi2LastSuccessfulTime the start of the refused step (pythonfmu 0.7's behaviour).
 *    fmi3DoStep: a result with a status (and terminateSimulation) attribute gives those;
 *    a false result is fmi3Discard (pythonfmu3's behaviour); the other out-arguments are
 *    always written.
 *  - fmi3EnterInitializationMode calls setup_experiment(startTime) before
 *    enter_initialization_mode(), as fmi2SetupExperiment does in FMI 2.0.
 *  - what FMI forbids is refused here, in C, before any Python runs, with the Error
 *    status and a message through the host's logger (see "the state machine" below): a
 *    call in a mode where FMI does not allow it, a step size <= 0 or not finite, a
 *    GUID / instantiationToken other than the one the build wrote into
 *    resources/agv_build.json, a get or set of a value reference that is not a variable
 *    of the call's type, a set of an output, of the independent variable, or of a fixed
 *    parameter after initialisation mode (the variables' types and causalities come from
 *    the slave's _fmi_variables() at instantiation). The slave refuses the rest
 *    (non-finite inputs, FMU states that are not its own) by raising an exception with
 *    the attribute fmi_error (SlaveLogic's CallRefused): that is an Error, not Fatal.
 */
#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <dlfcn.h>
#include <libgen.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <sys/stat.h>

#include "fmi2FunctionTypes.h"
#define FMI3_FUNCTION_PREFIX agv_
#include "fmi3Functions.h"

/* The FMI 2.0 functions get the agv_ prefix here (fmpy's fmi2Functions.h has no prefix
   macro); the attribute exports them. */
#define EXPORT2(name) __attribute__((visibility("default"))) agv_##name

/* ------------------------------------------------------------------ interned names */
static PyObject *s_stale, *s_core, *s_fresh_outputs, *s_status, *s_terminate_simulation,
    *s_time, *s_lazy_step, *s_step_failed, *s_outputs_failed;

static int intern_names(void)
{
    if (s_stale != NULL) return 1;
    s_stale = PyUnicode_InternFromString("_stale");
    s_core = PyUnicode_InternFromString("core");
    s_fresh_outputs = PyUnicode_InternFromString("_fresh_outputs");
    s_status = PyUnicode_InternFromString("status");
    s_terminate_simulation = PyUnicode_InternFromString("terminateSimulation");
    s_time = PyUnicode_InternFromString("time");
    s_lazy_step = PyUnicode_InternFromString("_lazy_step");
    s_step_failed = PyUnicode_InternFromString("_step_failed");
    s_outputs_failed = PyUnicode_InternFromString("_outputs_failed");
    return s_stale && s_core && s_fresh_outputs && s_status && s_terminate_simulation &&
           s_time && s_lazy_step && s_step_failed && s_outputs_failed;
}

/* ------------------------------------------------------------------ instance */
enum { REAL, INTEGER, BOOLEAN, STRING, N_KINDS };

static const char *const METHODS2[2][N_KINDS] = {
    {"get_real", "get_integer", "get_boolean", "get_string"},
    {"set_real", "set_integer", "set_boolean", "set_string"},
};
static const char *const METHODS3[2][N_KINDS] = {
    {"get_float64", "get_int32", "get_boolean", "get_string"},
    {"set_float64", "set_int32", "set_boolean", "set_string"},
};

typedef struct {
    int fmi3;
    char *name;
    int logging_on;
    fmi2CallbackLogger log2;
    fmi2ComponentEnvironment env2;
    fmi3LogMessageCallback log3;
    fmi3InstanceEnvironment env3;

    PyObject *cls;        /* the slave class */
    PyObject *kwargs;     /* its constructor's keyword arguments (fmi2Reset, fmi3Reset) */
    PyObject *slave;
    PyObject *log_queue;  /* the slave's list of queued log messages */
    PyObject *do_step, *terminate, *setup_experiment, *enter_init, *exit_init;
    PyObject *fresh_outputs; /* the Real fast path's refresh (bound method) */
    PyObject *advance, *publish; /* the step fast path's hooks (bound methods), or NULL */
    PyObject *get[N_KINDS], *set[N_KINDS];

    /* the Real fast path (see the file comment); NULL when the slave offers none */
    PyObject **real_names; /* value reference -> attribute name (or NULL) */
    unsigned char *quiet;  /* value reference -> 1 for an input no output depends on */
    size_t n_real_names;

    /* the last value-reference tuple per (get/set, kind): hosts pass the same ones */
    PyObject *vr_tuple[2][N_KINDS];

    PyObject *strings; /* the bytes behind the last fmi2GetString / fmi3GetString */
    double last_successful_time;
    int terminated;

    int mode; /* where the instance is in the FMI state machine (MODE_*) */
    /* the slave's variables by value reference (_fmi_variables()), for the checks of
       every get and set; var_type NULL when the slave describes none */
    size_t n_vars;
    unsigned char *var_type; /* 1 + VAR_* code, 0 for no variable */
    unsigned char *var_set;  /* SET_* code */
    char **var_name;

    /* the thread slots (see "the GIL on any thread") of the threads this instance took
       the GIL on through a slot; read and changed with the GIL held */
    struct ThreadSlot **slots;
    size_t n_slots, cap_slots;
} Instance;

/* ------------------------------------------------------------------ the GIL on any thread */
/* A thread Python knows (the interpreter's main thread, a Python thread calling through
   ctypes) takes the GIL with PyGILState_Ensure / PyGILState_Release: its thread state
   exists, nothing is created. A foreign thread (a host's worker thread) gets one thread
   state of the bridge's, its slot, made at its first call and kept in thread-local
   storage, so that later calls only take and give the GIL (PyEval_RestoreThread /
   PyEval_SaveThread) instead of creating and destroying a thread state each time.
   Every instance that ran on a slot holds it (users); the thread state is deleted on its
   own thread (which also clears Python's PyGILState pointer of that thread): when the
   last of its instances is freed on that thread, else when the thread exits. A thread
   that exits while instances still hold its slot deletes the thread state and leaves the
   slot to the last of them to free. */
typedef struct ThreadSlot {
    PyThreadState *ts; /* the thread's state; NULL once the thread has exited */
    int users;         /* live instances that ran on this slot */
    int depth;         /* gil_take calls not yet given back on this thread */
} ThreadSlot;

enum { GIL_SLOT = -1, GIL_NESTED = -2 }; /* gil_take's tokens beside PyGILState_STATE */

static __thread ThreadSlot *tl_slot;
static pthread_key_t slot_key;
static pthread_once_t slot_once = PTHREAD_ONCE_INIT;
static int slot_key_made;

static int interpreter_alive(void)
{
#if PY_VERSION_HEX >= 0x030D0000
    return Py_IsInitialized() && !Py_IsFinalizing();
#else
    return Py_IsInitialized() && !_Py_IsFinalizing();
#endif
}

/* Thread exit: delete the thread's state on its own thread, with the GIL. */
static void slot_exit(void *value)
{
    ThreadSlot *slot = value;
    tl_slot = NULL;
    if (slot == NULL || slot->ts == NULL) return;
    if (!interpreter_alive()) return; /* the interpreter is going: it clears the states */
    PyEval_RestoreThread(slot->ts);
    PyThreadState_Clear(slot->ts);
    slot->ts = NULL;
    int unused = slot->users == 0;
    PyThreadState_DeleteCurrent(); /* gives the GIL back */
    if (unused) free(slot);
}

static void make_slot_key(void) { slot_key_made = pthread_key_create(&slot_key, slot_exit) == 0; }

/* This thread's new slot, or NULL (then PyGILState_Ensure serves). */
static ThreadSlot *new_slot(void)
{
    pthread_once(&slot_once, make_slot_key);
    if (!slot_key_made) return NULL;
    ThreadSlot *slot = calloc(1, sizeof *slot);
    if (slot == NULL) return NULL;
    slot->ts = PyThreadState_New(PyInterpreterState_Main());
    if (slot->ts == NULL || pthread_setspecific(slot_key, slot) != 0) {
        if (slot->ts != NULL) PyThreadState_Delete(slot->ts);
        free(slot);
        return NULL;
    }
    tl_slot = slot;
    return slot;
}

/* Take the GIL for a call on `inst`; the token for gil_give. */
static int gil_take(Instance *inst)
{
    ThreadSlot *slot = tl_slot;
    if (slot == NULL) {
        if (PyGILState_GetThisThreadState() != NULL) return (int)PyGILState_Ensure();
        slot = new_slot();
        if (slot == NULL) return (int)PyGILState_Ensure();
    }
    if (slot->depth++ > 0) return GIL_NESTED; /* a call from within a call (a logger) */
    PyEval_RestoreThread(slot->ts);
    for (size_t i = 0; i < inst->n_slots; i++)
        if (inst->slots[i] == slot) return GIL_SLOT;
    if (inst->n_slots == inst->cap_slots) {
        size_t cap = inst->cap_slots ? 2 * inst->cap_slots : 4;
        ThreadSlot **grown = realloc(inst->slots, cap * sizeof *grown);
        if (grown == NULL) return GIL_SLOT; /* not held: then deleted at the thread's exit */
        inst->slots = grown;
        inst->cap_slots = cap;
    }
    inst->slots[inst->n_slots++] = slot;
    slot->users++;
    return GIL_SLOT;
}

/* Give back what gil_take(inst) took. */
static void gil_give(int token)
{
    if (token >= 0) {
        PyGILState_Release((PyGILState_STATE)token);
        return;
    }
    ThreadSlot *slot = tl_slot;
    if (--slot->depth > 0) return;
    if (slot->users > 0) {
        PyEval_SaveThread();
        return;
    }
    /* the last instance that ran on this thread's slot was freed: delete its state */
    tl_slot = NULL;
    pthread_setspecific(slot_key, NULL);
    PyThreadState_Clear(slot->ts);
    PyThreadState_DeleteCurrent(); /* gives the GIL back */
    free(slot);
}

/* An instance being freed lets go of its slots (with the GIL held). */
static void drop_slots(Instance *inst)
{
    for (size_t i = 0; i < inst->n_slots; i++) {
        ThreadSlot *slot = inst->slots[i];
        /* a slot whose thread has exited is freed by its last user */
        if (--slot->users == 0 && slot->ts == NULL) free(slot);
    }
    free(inst->slots);
    inst->slots = NULL;
    inst->n_slots = inst->cap_slots = 0;
}

/* ------------------------------------------------------------------ messages */
static void emit(Instance *inst, int status, const char *category, const char *message)
{
    if (inst->fmi3) {
        if (inst->log3) inst->log3(inst->env3, (fmi3Status)status, category, message);
    } else if (inst->log2) {
        inst->log2(inst->env2, inst->name, (fmi2Status)status, category, "%s", message);
    }
}

static void emitf(Instance *inst, int status, const char *category, const char *format, ...)
{
    char message[1024];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    emit(inst, status, category, message);
}

/* Pass the slave's queued messages (pythonfmu LogMsg: status, category, msg) to the host;
   messages with status OK only when logging is on. Called with the GIL held. */
static void flush_log(Instance *inst)
{
    PyObject *queue = inst->log_queue;
    if (queue == NULL || !PyList_Check(queue) || PyList_GET_SIZE(queue) == 0) return;
    PyObject *saved_type, *saved_value, *saved_tb;
    PyErr_Fetch(&saved_type, &saved_value, &saved_tb);
    Py_ssize_t n = PyList_GET_SIZE(queue);
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PyList_GET_ITEM(queue, i);
        PyObject *status = PyObject_GetAttrString(item, "status");
        PyObject *category = PyObject_GetAttrString(item, "category");
        PyObject *msg = PyObject_GetAttrString(item, "msg");
        long level = status ? PyLong_AsLong(status) : 0;
        if (level < 0) level = 0;
        const char *cat = (category && PyUnicode_Check(category)) ? PyUnicode_AsUTF8(category)
                                                                   : NULL;
        PyObject *text = msg ? PyObject_Str(msg) : NULL;
        const char *utf8 = text ? PyUnicode_AsUTF8(text) : NULL;
        if (level > 0 || inst->logging_on) {
            emit(inst, (int)level, cat ? cat : "", utf8 ? utf8 : "(unprintable message)");
        }
        PyErr_Clear();
        Py_XDECREF(status);
        Py_XDECREF(category);
        Py_XDECREF(msg);
        Py_XDECREF(text);
    }
    PyList_SetSlice(queue, 0, n, NULL);
    PyErr_Clear();
    PyErr_Restore(saved_type, saved_value, saved_tb);
}

/* A pending Python exception that is a refusal (SlaveLogic's CallRefused: it has
   fmi_error): its message logged (the slave's own, queued, or else its text); 1. Else
   0, the exception still pending. */
static int refusal(Instance *inst)
{
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    if (value == NULL || !PyObject_HasAttrString(value, "fmi_error")) {
        PyErr_Restore(type, value, tb);
        return 0;
    }
    int queued = inst->log_queue && PyList_Check(inst->log_queue) &&
                 PyList_GET_SIZE(inst->log_queue) > 0;
    flush_log(inst);
    if (!queued) {
        PyObject *text = PyObject_Str(value);
        const char *utf8 = text ? PyUnicode_AsUTF8(text) : NULL;
        emit(inst, inst->fmi3 ? (int)fmi3Error : (int)fmi2Error, "logStatusError",
             utf8 ? utf8 : "refused");
        Py_XDECREF(text);
    }
    PyErr_Clear();
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    return 1;
}

/* Log the pending Python exception as the failure of `what`; the fatal status (the
   error status for a refusal, see refusal()). */
static int failed(Instance *inst, const char *what)
{
    if (refusal(inst)) return inst->fmi3 ? (int)fmi3Error : (int)fmi2Error;
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    flush_log(inst); /* the slave's own message first */
    const char *type_name = type ? ((PyTypeObject *)type)->tp_name : "error";
    PyObject *text = value ? PyObject_Str(value) : NULL;
    const char *utf8 = text ? PyUnicode_AsUTF8(text) : NULL;
    PyErr_Clear();
    emitf(inst, inst->fmi3 ? (int)fmi3Fatal : (int)fmi2Fatal, "logStatusFatal",
          "%s failed: %s: %s", what, type_name, utf8 ? utf8 : "");
    Py_XDECREF(text);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    return inst->fmi3 ? (int)fmi3Fatal : (int)fmi2Fatal;
}

#define OK_STATUS(inst) ((inst)->fmi3 ? (int)fmi3OK : (int)fmi2OK)
#define ERROR_STATUS(inst) ((inst)->fmi3 ? (int)fmi3Error : (int)fmi2Error)

/* ------------------------------------------------------------------ the state machine
   The FMI 2.0 / 3.0 co-simulation state machine (without event mode). Every function
   first checks that the instance is in a mode where FMI allows it; a call outside them
   returns fmi2Error / fmi3Error with a message through the host's logger. A call that
   returns Error leaves the instance in MODE_ERROR (then only getters, the FMU-state
   functions, reset and free are allowed: FMI's "the simulation cannot be continued
   with this instance" unless a saved state is restored or it is reset), one that
   returns Fatal in MODE_FATAL (free only). A restored FMU state brings back the mode it
   was saved in (SlaveLogic._get_fmu_state records it). */
enum {
    MODE_INSTANTIATED = 1, MODE_INITIALIZATION = 2, MODE_STEP = 4, MODE_STEP_FAILED = 8,
    MODE_TERMINATED = 16, MODE_ERROR = 32, MODE_FATAL = 64
};
#define MODES_ALIVE (MODE_INSTANTIATED | MODE_INITIALIZATION | MODE_STEP | MODE_STEP_FAILED | \
                     MODE_TERMINATED | MODE_ERROR)
/* getters: FMI 2.0 not before initialisation mode; FMI 3.0 also in Instantiated (as the
   Reference FMUs) */
#define MODES_GET(inst) (((inst)->fmi3 ? MODE_INSTANTIATED : 0) | MODE_INITIALIZATION | \
                         MODE_STEP | MODE_STEP_FAILED | MODE_TERMINATED | MODE_ERROR)
#define MODES_SET (MODE_INSTANTIATED | MODE_INITIALIZATION | MODE_STEP)
#define MODES_STATUS (MODE_STEP | MODE_STEP_FAILED | MODE_TERMINATED)

/* codes of SlaveLogic._fmi_variables (agv_core/fmi/slave_base.py) */
enum { SET_NEVER, SET_INPUT, SET_OUTPUT, SET_FIXED, SET_TUNABLE };

static const char *mode_phrase(const Instance *inst)
{
    switch (inst->mode) {
    case MODE_INSTANTIATED: return "before initialisation mode (instantiated)";
    case MODE_INITIALIZATION: return "in initialisation mode";
    case MODE_STEP: return "in step mode";
    case MODE_STEP_FAILED:
        return inst->fmi3 ? "after a discarded step" : "after a discarded step (fmi2Discard)";
    case MODE_TERMINATED:
        return inst->fmi3 ? "after fmi3Terminate (only fmi3Reset or fmi3FreeInstance go on)"
                          : "after fmi2Terminate (only fmi2Reset or fmi2FreeInstance go on)";
    case MODE_ERROR:
        return inst->fmi3 ? "after an error (restore a saved state with fmi3SetFMUState, or "
                            "fmi3Reset, or fmi3FreeInstance)"
                          : "after an error (restore a saved state with fmi2SetFMUstate, or "
                            "fmi2Reset, or fmi2FreeInstance)";
    default:
        return inst->fmi3 ? "after a fatal error (only fmi3FreeInstance)"
                          : "after a fatal error (only fmi2FreeInstance)";
    }
}

/* The status of a call that ended with `status`: Error and Fatal move the instance to
   MODE_ERROR / MODE_FATAL. */
static int settle(Instance *inst, int status)
{
    if (status == (int)fmi2Fatal) inst->mode = MODE_FATAL;
    else if (status == (int)fmi2Error && inst->mode != MODE_FATAL) inst->mode = MODE_ERROR;
    return status;
}

/* A call that moves the instance to `next` when it succeeds. */
static int moved(Instance *inst, int status, int next)
{
    if (status == OK_STATUS(inst)) inst->mode = next;
    return settle(inst, status);
}

/* Refuse `what` (logged, Error) with the reason `why`. */
static int refuse(Instance *inst, const char *what, const char *why)
{
    emitf(inst, ERROR_STATUS(inst), "logStatusError", "%s: refused: %s", what, why);
    return settle(inst, ERROR_STATUS(inst));
}

/* 0 when the instance is in one of `modes`, else the refusal of `what`. */
static int not_in(Instance *inst, int modes, const char *what)
{
    if (inst->mode & modes) return 0;
    char why[320];
    snprintf(why, sizeof why, "not allowed %s", mode_phrase(inst));
    return refuse(inst, what, why);
}

static const char *const TYPE_NAMES[2][4] = {{"Real", "Integer", "Boolean", "String"},
                                             {"Float64", "Int32", "Boolean", "String"}};

/* 0 when a get (set = 0) or set of `n` variables of type `kind` is allowed now: the
   mode, each value reference a variable of that type, and for a set each variable one a
   host may set in this mode (an input or a tunable parameter; a fixed parameter only
   before initialisation mode ends; never an output or the independent variable). Else
   the refusal of `what`, naming the variable. */
static int check_values(Instance *inst, const char *what, int set, int kind,
                        const unsigned int *vr, size_t n)
{
    int refused = not_in(inst, set ? MODES_SET : MODES_GET(inst), what);
    if (refused || inst->var_type == NULL || n == 0) return refused;
    if (vr == NULL) return refuse(inst, what, "no value references given");
    const char *const *types = TYPE_NAMES[inst->fmi3 ? 1 : 0];
    char why[512];
    for (size_t i = 0; i < n; i++) {
        unsigned int r = vr[i];
        int type = r < inst->n_vars ? inst->var_type[r] : 0;
        if (type != kind + 1) {
            if (type == 0)
                snprintf(why, sizeof why, "value reference %u is no variable of this FMU", r);
            else
                snprintf(why, sizeof why, "value reference %u is '%s', a %s, not a %s", r,
                         inst->var_name[r], types[type - 1], types[kind]);
            return refuse(inst, what, why);
        }
        if (!set) continue;
        int access = inst->var_set[r];
        if (access == SET_INPUT || access == SET_TUNABLE ||
            (access == SET_FIXED && inst->mode != MODE_STEP))
            continue;
        if (access == SET_OUTPUT)
            snprintf(why, sizeof why, "'%s' is an output: a host never sets it",
                     inst->var_name[r]);
        else if (access == SET_FIXED)
            snprintf(why, sizeof why, "'%s' is a fixed parameter: it can be set only before "
                     "%s, not %s (tunable parameters and inputs can)", inst->var_name[r],
                     inst->fmi3 ? "fmi3ExitInitializationMode" : "fmi2ExitInitializationMode",
                     mode_phrase(inst));
        else
            snprintf(why, sizeof why, "'%s' cannot be set (not an input or a parameter)",
                     inst->var_name[r]);
        return refuse(inst, what, why);
    }
    return 0;
}

#define CHECK_VALUES(inst, what, set, kind)                                               \
    do {                                                                                  \
        int refused_ = check_values(inst, what, set, kind, vr, n);                        \
        if (refused_) return refused_;                                                    \
    } while (0)

/* 0 when a step from `t` of size `h` is allowed: in step mode, a finite time and a
   finite step size > 0 (FMI: communicationStepSize > 0); else the refusal. */
static int check_step(Instance *inst, const char *what, double t, double h)
{
    int refused = not_in(inst, MODE_STEP, what);
    if (refused) return refused;
    if (isfinite(t) && isfinite(h) && h > 0.0) return 0;
    char why[256];
    snprintf(why, sizeof why, "communicationStepSize %.17g from currentCommunicationPoint "
             "%.17g: the step size must be a finite number > 0 and the time finite", h, t);
    return refuse(inst, what, why);
}

/* The mode a restored FMU state was saved in (its "mode"; step mode if it names none). */
static int saved_mode(PyObject *state)
{
    static const char *const names[] = {"instantiated", "initialization", "step",
                                        "terminated"};
    static const int modes[] = {MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEP,
                                MODE_TERMINATED};
    PyObject *mode = PyDict_Check(state) ? PyDict_GetItemString(state, "mode") : NULL;
    const char *text = mode && PyUnicode_Check(mode) ? PyUnicode_AsUTF8(mode) : NULL;
    PyErr_Clear();
    for (int i = 0; text && i < 4; i++) {
        if (strcmp(text, names[i]) == 0) return modes[i];
    }
    return MODE_STEP;
}

/* The GUID (FMI 2.0) / instantiation token (FMI 3.0) the build wrote into the FMU's
   resources/agv_build.json ("guid"); "" when it has none; NULL when out of memory. */
static char *built_token(const char *resources)
{
    char path[PATH_MAX + 32], text[16384];
    snprintf(path, sizeof path, "%s/agv_build.json", resources);
    FILE *file = fopen(path, "rb");
    if (file == NULL) return strdup("");
    size_t size = fread(text, 1, sizeof text - 1, file);
    fclose(file);
    text[size] = '\0';
    const char *p = strstr(text, "\"guid\"");
    if (p == NULL) return strdup("");
    p += 6;
    while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n') p++;
    if (*p++ != ':') return strdup("");
    while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n') p++;
    if (*p++ != '"') return strdup("");
    const char *end = strchr(p, '"');
    return end ? strndup(p, (size_t)(end - p)) : strdup("");
}

/* ------------------------------------------------------------------ Python helpers */
static PyObject *call0(PyObject *callable)
{
    return PyObject_Vectorcall(callable, NULL, 0, NULL);
}

static PyObject *call1(PyObject *callable, PyObject *arg)
{
    PyObject *args[2] = {NULL, arg};
    return PyObject_Vectorcall(callable, args + 1, 1 | PY_VECTORCALL_ARGUMENTS_OFFSET, NULL);
}

static PyObject *call2(PyObject *callable, PyObject *a, PyObject *b)
{
    PyObject *args[3] = {NULL, a, b};
    return PyObject_Vectorcall(callable, args + 1, 2 | PY_VECTORCALL_ARGUMENTS_OFFSET, NULL);
}

/* The value references as a tuple of ints; the tuple of the previous call of the same
   kind is reused when it holds the same numbers. New reference. */
static PyObject *vr_tuple(Instance *inst, int set, int kind, const unsigned int *vr, size_t n)
{
    PyObject *cached = inst->vr_tuple[set][kind];
    if (cached != NULL && (size_t)PyTuple_GET_SIZE(cached) == n) {
        size_t i = 0;
        for (; i < n; i++) {
            if (PyLong_AsUnsignedLong(PyTuple_GET_ITEM(cached, i)) != vr[i]) break;
        }
        if (i == n) {
            Py_INCREF(cached);
            return cached;
        }
    }
    PyObject *tuple = PyTuple_New((Py_ssize_t)n);
    if (tuple == NULL) return NULL;
    for (size_t i = 0; i < n; i++) {
        PyObject *number = PyLong_FromUnsignedLong(vr[i]);
        if (number == NULL) {
            Py_DECREF(tuple);
            return NULL;
        }
        PyTuple_SET_ITEM(tuple, i, number);
    }
    Py_XSETREF(inst->vr_tuple[set][kind], tuple);
    Py_INCREF(tuple);
    return tuple;
}

/* Call the slave's getter of `kind`; its result as a fast sequence of n items. */
static PyObject *get_values(Instance *inst, int kind, const unsigned int *vr, size_t n)
{
    PyObject *vrs = vr_tuple(inst, 0, kind, vr, n);
    if (vrs == NULL) return NULL;
    PyObject *result = call1(inst->get[kind], vrs);
    Py_DECREF(vrs);
    if (result == NULL) return NULL;
    PyObject *values = PySequence_Fast(result, "a getter must return a sequence");
    Py_DECREF(result);
    if (values != NULL && (size_t)PySequence_Fast_GET_SIZE(values) < n) {
        PyErr_Format(PyExc_ValueError, "a getter returned %zd values for %zu value "
                     "references", PySequence_Fast_GET_SIZE(values), n);
        Py_CLEAR(values);
    }
    return values;
}

/* Call the slave's setter of `kind` with `values` (a list, stolen). */
static int set_values(Instance *inst, int kind, const unsigned int *vr, size_t n,
                      PyObject *values)
{
    if (values == NULL) return -1;
    PyObject *vrs = vr_tuple(inst, 1, kind, vr, n);
    if (vrs == NULL) {
        Py_DECREF(values);
        return -1;
    }
    PyObject *result = call2(inst->set[kind], vrs, values);
    Py_DECREF(vrs);
    Py_DECREF(values);
    if (result == NULL) return -1;
    Py_DECREF(result);
    return 0;
}

/* The attribute name of a Real value reference on the fast path, or NULL. */
static inline PyObject *real_name(Instance *inst, unsigned int vr)
{
    return vr < inst->n_real_names ? inst->real_names[vr] : NULL;
}

/* An exception (an Exception) from a hook goes to the slave's reporting method
   (_step_failed(t, error) / _outputs_failed(error)), which logs it and raises; -1. */
static int hook_failed(Instance *inst, PyObject *method, PyObject *time)
{
    if (!PyErr_ExceptionMatches(PyExc_Exception)) return -1;
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    if (tb != NULL && value != NULL) PyException_SetTraceback(value, tb);
    PyObject *result = time ? PyObject_CallMethodObjArgs(inst->slave, method, time, value, NULL)
                            : PyObject_CallMethodObjArgs(inst->slave, method, value, NULL);
    if (result != NULL) { /* it did not raise: keep the original exception */
        Py_DECREF(result);
        PyErr_Restore(type, value, tb);
        return -1;
    }
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    return -1;
}

/* Before a read on the Real fast path: what SlaveLogic._fresh_outputs does (see
   _fmi_real_access): without a core the slave's own method, else with stale outputs
   publish() and _stale = False. 0, or -1 with a Python exception. */
static int refresh_outputs(Instance *inst)
{
    PyObject *core = PyObject_GetAttr(inst->slave, s_core);
    if (core == NULL) return -1;
    int no_core = core == Py_None;
    Py_DECREF(core);
    PyObject *done;
    if (no_core) {
        done = call0(inst->fresh_outputs);
    } else {
        PyObject *stale = PyObject_GetAttr(inst->slave, s_stale);
        if (stale == NULL) return -1;
        int is_stale = PyObject_IsTrue(stale);
        Py_DECREF(stale);
        if (is_stale <= 0) return is_stale;
        done = call0(inst->publish);
        if (done == NULL) return hook_failed(inst, s_outputs_failed, NULL);
        Py_DECREF(done);
        return PyObject_SetAttr(inst->slave, s_stale, Py_False);
    }
    if (done == NULL) return -1;
    Py_DECREF(done);
    return 0;
}

static int get_reals(Instance *inst, const unsigned int *vr, size_t n, double *out)
{
    if (inst->real_names != NULL) {
        size_t i = 0;
        while (i < n && real_name(inst, vr[i]) != NULL) i++;
        if (i == n) {
            if (refresh_outputs(inst) < 0) return -1;
            for (i = 0; i < n; i++) {
                PyObject *value = PyObject_GetAttr(inst->slave, inst->real_names[vr[i]]);
                if (value == NULL) return -1;
                out[i] = PyFloat_AsDouble(value);
                Py_DECREF(value);
                if (out[i] == -1.0 && PyErr_Occurred()) return -1;
            }
            return 0;
        }
    }
    PyObject *values = get_values(inst, REAL, vr, n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(values, i));
        if (out[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(values);
            return -1;
        }
    }
    Py_DECREF(values);
    return 0;
}

static int set_reals(Instance *inst, const unsigned int *vr, size_t n, const double *in)
{
    if (inst->real_names != NULL) {
        /* a value that is not finite takes the slave's own setter, which refuses it
           for an input (SlaveLogic._check_finite_inputs) */
        size_t i = 0;
        while (i < n && real_name(inst, vr[i]) != NULL && isfinite(in[i])) i++;
        if (i == n) {
            int stale = 0;
            for (i = 0; i < n; i++) {
                PyObject *value = PyFloat_FromDouble(in[i]);
                if (value == NULL) return -1;
                int done = PyObject_SetAttr(inst->slave, inst->real_names[vr[i]], value);
                Py_DECREF(value);
                if (done < 0) return -1;
                if (!inst->quiet[vr[i]]) stale = 1;
            }
            return stale ? PyObject_SetAttr(inst->slave, s_stale, Py_True) : 0;
        }
    }
    PyObject *values = PyList_New((Py_ssize_t)n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        PyObject *value = PyFloat_FromDouble(in[i]);
        if (value == NULL) {
            Py_DECREF(values);
            return -1;
        }
        PyList_SET_ITEM(values, i, value);
    }
    return set_values(inst, REAL, vr, n, values);
}

static int get_ints(Instance *inst, const unsigned int *vr, size_t n, int *out)
{
    PyObject *values = get_values(inst, INTEGER, vr, n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        long value = PyLong_AsLong(PySequence_Fast_GET_ITEM(values, i));
        if (value == -1 && PyErr_Occurred()) {
            Py_DECREF(values);
            return -1;
        }
        out[i] = (int)value;
    }
    Py_DECREF(values);
    return 0;
}

static int set_ints(Instance *inst, const unsigned int *vr, size_t n, const int *in)
{
    PyObject *values = PyList_New((Py_ssize_t)n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        PyObject *value = PyLong_FromLong(in[i]);
        if (value == NULL) {
            Py_DECREF(values);
            return -1;
        }
        PyList_SET_ITEM(values, i, value);
    }
    return set_values(inst, INTEGER, vr, n, values);
}

/* Booleans: fmi2Boolean is an int, fmi3Boolean a bool; `wide` says which. */
static int get_bools(Instance *inst, const unsigned int *vr, size_t n, void *out, int wide)
{
    PyObject *values = get_values(inst, BOOLEAN, vr, n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        int truth = PyObject_IsTrue(PySequence_Fast_GET_ITEM(values, i));
        if (truth < 0) {
            Py_DECREF(values);
            return -1;
        }
        if (wide) ((fmi2Boolean *)out)[i] = truth;
        else ((fmi3Boolean *)out)[i] = truth;
    }
    Py_DECREF(values);
    return 0;
}

static int set_bools(Instance *inst, const unsigned int *vr, size_t n, const void *in, int wide)
{
    PyObject *values = PyList_New((Py_ssize_t)n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        long truth = wide ? ((const fmi2Boolean *)in)[i] : ((const fmi3Boolean *)in)[i];
        PyList_SET_ITEM(values, i, PyBool_FromLong(truth));
    }
    return set_values(inst, BOOLEAN, vr, n, values);
}

static int get_strings(Instance *inst, const unsigned int *vr, size_t n, const char **out)
{
    PyObject *values = get_values(inst, STRING, vr, n);
    if (values == NULL) return -1;
    PyObject *kept = PyList_New((Py_ssize_t)n);
    if (kept == NULL) {
        Py_DECREF(values);
        return -1;
    }
    for (size_t i = 0; i < n; i++) {
        PyObject *text = PyObject_Str(PySequence_Fast_GET_ITEM(values, i));
        PyObject *bytes = text ? PyUnicode_AsUTF8String(text) : NULL;
        Py_XDECREF(text);
        if (bytes == NULL) {
            Py_DECREF(kept);
            Py_DECREF(values);
            return -1;
        }
        PyList_SET_ITEM(kept, i, bytes);
        out[i] = PyBytes_AS_STRING(bytes);
    }
    Py_DECREF(values);
    /* valid until the next call that returns strings */
    Py_XSETREF(inst->strings, kept);
    return 0;
}

static int set_strings(Instance *inst, const unsigned int *vr, size_t n, const char *const *in)
{
    PyObject *values = PyList_New((Py_ssize_t)n);
    if (values == NULL) return -1;
    for (size_t i = 0; i < n; i++) {
        PyObject *value = PyUnicode_FromString(in[i] ? in[i] : "");
        if (value == NULL) {
            Py_DECREF(values);
            return -1;
        }
        PyList_SET_ITEM(values, i, value);
    }
    return set_values(inst, STRING, vr, n, values);
}

/* ------------------------------------------------------------------ the slave */
static void drop_slave(Instance *inst)
{
    for (int k = 0; k < N_KINDS; k++) {
        Py_CLEAR(inst->get[k]);
        Py_CLEAR(inst->set[k]);
        Py_CLEAR(inst->vr_tuple[0][k]);
        Py_CLEAR(inst->vr_tuple[1][k]);
    }
    Py_CLEAR(inst->do_step);
    Py_CLEAR(inst->terminate);
    Py_CLEAR(inst->setup_experiment);
    Py_CLEAR(inst->enter_init);
    Py_CLEAR(inst->exit_init);
    Py_CLEAR(inst->fresh_outputs);
    Py_CLEAR(inst->advance);
    Py_CLEAR(inst->publish);
    if (inst->real_names != NULL) {
        for (size_t i = 0; i < inst->n_real_names; i++) Py_XDECREF(inst->real_names[i]);
        free(inst->real_names);
        inst->real_names = NULL;
    }
    free(inst->quiet);
    inst->quiet = NULL;
    inst->n_real_names = 0;
    for (size_t i = 0; inst->var_name != NULL && i < inst->n_vars; i++) free(inst->var_name[i]);
    free(inst->var_name);
    free(inst->var_type);
    free(inst->var_set);
    inst->var_name = NULL;
    inst->var_type = inst->var_set = NULL;
    inst->n_vars = 0;
    Py_CLEAR(inst->log_queue);
    Py_CLEAR(inst->slave);
    Py_CLEAR(inst->strings);
}

/* The Real fast path the slave offers through _fmi_real_access(), if any. */
static int real_access(Instance *inst)
{
    if (!PyObject_HasAttrString(inst->slave, "_fmi_real_access")) return 0;
    PyObject *access = PyObject_CallMethod(inst->slave, "_fmi_real_access", NULL);
    if (access == NULL) return -1;
    if (access == Py_None) {
        Py_DECREF(access);
        return 0;
    }
    inst->fresh_outputs = PyObject_GetAttr(inst->slave, s_fresh_outputs);
    inst->publish = inst->fresh_outputs ? PyObject_GetAttrString(inst->slave, "publish") : NULL;
    if (inst->fresh_outputs == NULL || inst->publish == NULL) {
        Py_DECREF(access);
        return -1;
    }
    PyObject *names = NULL, *quiet = NULL;
    int ok = PyTuple_Check(access) && PyArg_ParseTuple(access, "O!O", &PyDict_Type, &names,
                                                       &quiet);
    if (!ok) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_TypeError, "_fmi_real_access() must return (dict, set)");
        Py_DECREF(access);
        return -1;
    }
    size_t size = 0;
    PyObject *key, *value;
    Py_ssize_t pos = 0;
    while (PyDict_Next(names, &pos, &key, &value)) {
        unsigned long vr = PyLong_AsUnsignedLong(key);
        if (PyErr_Occurred() || !PyUnicode_Check(value)) {
            PyErr_Clear();
            PyErr_SetString(PyExc_TypeError, "_fmi_real_access(): names maps int to str");
            Py_DECREF(access);
            return -1;
        }
        if (vr + 1 > size) size = vr + 1;
    }
    if (size > (1u << 20)) size = 0; /* implausible: take the slave's own methods */
    inst->real_names = calloc(size ? size : 1, sizeof(PyObject *));
    inst->quiet = calloc(size ? size : 1, 1);
    if (inst->real_names == NULL || inst->quiet == NULL) {
        Py_DECREF(access);
        PyErr_NoMemory();
        return -1;
    }
    inst->n_real_names = size;
    pos = 0;
    while (size && PyDict_Next(names, &pos, &key, &value)) {
        unsigned long vr = PyLong_AsUnsignedLong(key);
        Py_INCREF(value);
        PyUnicode_InternInPlace(&value);
        inst->real_names[vr] = value;
    }
    PyObject *iterator = PyObject_GetIter(quiet);
    if (iterator == NULL) {
        Py_DECREF(access);
        return -1;
    }
    PyObject *item;
    while ((item = PyIter_Next(iterator)) != NULL) {
        unsigned long vr = PyLong_AsUnsignedLong(item);
        Py_DECREF(item);
        if (PyErr_Occurred()) break;
        if (vr < size) inst->quiet[vr] = 1;
    }
    Py_DECREF(iterator);
    Py_DECREF(access);
    return PyErr_Occurred() ? -1 : 0;
}

/* The step fast path the slave offers through _fmi_step_access(), if any. */
static int step_access(Instance *inst)
{
    if (inst->publish == NULL || !PyObject_HasAttrString(inst->slave, "_fmi_step_access"))
        return 0;
    PyObject *allowed = PyObject_CallMethod(inst->slave, "_fmi_step_access", NULL);
    if (allowed == NULL) return -1;
    int yes = PyObject_IsTrue(allowed);
    Py_DECREF(allowed);
    if (yes < 0) return -1;
    if (yes) {
        inst->advance = PyObject_GetAttrString(inst->slave, "advance");
        if (inst->advance == NULL) return -1;
    }
    return 0;
}

/* The variables the slave describes through _fmi_variables(), if it does:
   ((value reference, name, type code, set code), ...). 0, or -1 with an exception. */
static int variables_table(Instance *inst)
{
    if (!PyObject_HasAttrString(inst->slave, "_fmi_variables")) return 0;
    PyObject *rows = PyObject_CallMethod(inst->slave, "_fmi_variables", NULL);
    PyObject *fast = rows ? PySequence_Fast(rows, "_fmi_variables() must return rows") : NULL;
    Py_XDECREF(rows);
    if (fast == NULL) return -1;
    Py_ssize_t count = PySequence_Fast_GET_SIZE(fast);
    size_t size = 0;
    for (Py_ssize_t i = 0; i < count; i++) {
        unsigned int vr;
        const char *name;
        int type, access;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(fast, i), "Isii", &vr, &name, &type,
                              &access)) {
            Py_DECREF(fast);
            return -1;
        }
        if ((size_t)vr + 1 > size) size = (size_t)vr + 1;
    }
    if (size > (1u << 20)) { /* implausible: no checks */
        Py_DECREF(fast);
        return 0;
    }
    inst->var_type = calloc(size ? size : 1, 1);
    inst->var_set = calloc(size ? size : 1, 1);
    inst->var_name = calloc(size ? size : 1, sizeof(char *));
    if (inst->var_type == NULL || inst->var_set == NULL || inst->var_name == NULL) {
        Py_DECREF(fast);
        PyErr_NoMemory();
        return -1;
    }
    inst->n_vars = size;
    for (Py_ssize_t i = 0; i < count; i++) {
        unsigned int vr;
        const char *name;
        int type, access;
        PyArg_ParseTuple(PySequence_Fast_GET_ITEM(fast, i), "Isii", &vr, &name, &type, &access);
        if (type < 0 || type >= N_KINDS) continue;
        inst->var_type[vr] = (unsigned char)(type + 1);
        inst->var_set[vr] = (unsigned char)access;
        free(inst->var_name[vr]);
        inst->var_name[vr] = strdup(name);
        if (inst->var_name[vr] == NULL) {
            Py_DECREF(fast);
            PyErr_NoMemory();
            return -1;
        }
    }
    Py_DECREF(fast);
    return 0;
}

/* Create the slave object from inst->cls and look up its methods. */
static int make_slave(Instance *inst)
{
    PyObject *empty = PyTuple_New(0);
    if (empty == NULL) return -1;
    inst->slave = PyObject_Call(inst->cls, empty, inst->kwargs);
    Py_DECREF(empty);
    if (inst->slave == NULL) return -1;
    const char *const(*methods)[N_KINDS] = inst->fmi3 ? METHODS3 : METHODS2;
    for (int k = 0; k < N_KINDS; k++) {
        inst->get[k] = PyObject_GetAttrString(inst->slave, methods[0][k]);
        inst->set[k] = PyObject_GetAttrString(inst->slave, methods[1][k]);
        if (inst->get[k] == NULL || inst->set[k] == NULL) return -1;
    }
    inst->do_step = PyObject_GetAttrString(inst->slave, "do_step");
    inst->terminate = PyObject_GetAttrString(inst->slave, "terminate");
    inst->setup_experiment = PyObject_GetAttrString(inst->slave, "setup_experiment");
    inst->enter_init = PyObject_GetAttrString(inst->slave, "enter_initialization_mode");
    inst->exit_init = PyObject_GetAttrString(inst->slave, "exit_initialization_mode");
    inst->log_queue = PyObject_GetAttrString(inst->slave, "log_queue");
    if (!inst->do_step || !inst->terminate || !inst->setup_experiment || !inst->enter_init ||
        !inst->exit_init || !inst->log_queue) {
        return -1;
    }
    if (real_access(inst) < 0 || step_access(inst) < 0 || variables_table(inst) < 0) return -1;
    inst->mode = MODE_INSTANTIATED;
    return 0;
}

/* A file URI (file:///a%20b/resources) or a path, as a path; malloc'ed. */
static char *resource_path(const char *location)
{
    if (location == NULL) return strdup("");
    const char *p = location;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0) p += 9;
    } else if (strncmp(p, "file:/", 6) == 0) {
        p += 5;
    }
    char *path = malloc(strlen(p) + 1), *out = path;
    if (path == NULL) return NULL;
    for (; *p; p++) {
        if (*p == '%' && p[1] && p[2]) {
            char hex[3] = {p[1], p[2], 0};
            char *end;
            long byte = strtol(hex, &end, 16);
            if (*end == '\0') {
                *out++ = (char)byte;
                p += 2;
                continue;
            }
        }
        *out++ = *p;
    }
    *out = '\0';
    size_t length = strlen(path);
    while (length > 1 && path[length - 1] == '/') path[--length] = '\0';
    return path;
}

/* A standalone FMU's packages (python/lib/python3.X/site-packages beside this library)
   appended to sys.path when they are not on it: the interpreter is then the host's (its
   packages come first), and the FMU's fill in what the host lacks. 0, or -1. */
static int add_own_packages(PyObject *sys_path)
{
    Dl_info info;
    if (!dladdr((void *)&add_own_packages, &info) || info.dli_fname == NULL) return 0;
    char copy[PATH_MAX], packages[PATH_MAX + 64];
    snprintf(copy, sizeof copy, "%s", info.dli_fname);
    snprintf(packages, sizeof packages, "%s/python/lib/python%d.%d/site-packages",
             dirname(copy), PY_MAJOR_VERSION, PY_MINOR_VERSION);
    struct stat status;
    if (stat(packages, &status) != 0 || !S_ISDIR(status.st_mode)) return 0;
    PyObject *folder = PyUnicode_DecodeFSDefault(packages);
    if (folder == NULL) return -1;
    int present = PySequence_Contains(sys_path, folder);
    int done = present != 0 ? present : PyList_Append(sys_path, folder);
    Py_DECREF(folder);
    return done < 0 ? -1 : 0;
}

/* Import (or re-execute) the slave module of `resources`; the slave class. New ref. */
static PyObject *slave_class(const char *resources)
{
    char file[4096];
    snprintf(file, sizeof file, "%s/slavemodule.txt", resources);
    FILE *handle = fopen(file, "r");
    if (handle == NULL) {
        PyErr_Format(PyExc_FileNotFoundError, "cannot read %s", file);
        return NULL;
    }
    char module_name[256] = "";
    if (fgets(module_name, sizeof module_name, handle) == NULL) module_name[0] = '\0';
    fclose(handle);
    module_name[strcspn(module_name, "\r\n")] = '\0';
    if (module_name[0] == '\0') {
        PyErr_Format(PyExc_ValueError, "%s names no module", file);
        return NULL;
    }

    PyObject *sys_path = PySys_GetObject("path"); /* borrowed */
    PyObject *folder = PyUnicode_DecodeFSDefault(resources);
    if (sys_path == NULL || folder == NULL || PyList_Insert(sys_path, 0, folder) < 0) {
        Py_XDECREF(folder);
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_RuntimeError, "no sys.path");
        return NULL;
    }
    Py_DECREF(folder);
    if (add_own_packages(sys_path) < 0) return NULL;

    PyObject *modules = PyImport_GetModuleDict(); /* borrowed */
    PyObject *loaded = PyDict_GetItemString(modules, module_name);
    PyObject *module;
    if (loaded != NULL) {
        /* Another instance imported it (maybe from another FMU's folder): execute it again
           with this FMU's resources first on sys.path, as pythonfmu does. */
        PyObject *importlib = PyImport_ImportModule("importlib");
        module = importlib ? PyObject_CallMethod(importlib, "reload", "O", loaded) : NULL;
        Py_XDECREF(importlib);
    } else {
        module = PyImport_ImportModule(module_name);
    }
    if (module == NULL) return NULL;

    PyObject *dict = PyModule_GetDict(module); /* borrowed */
    PyObject *own_name = PyModule_GetNameObject(module);
    PyObject *found = NULL, *key, *value;
    Py_ssize_t pos = 0;
    int count = 0;
    while (own_name && PyDict_Next(dict, &pos, &key, &value)) {
        if (!PyType_Check(value)) continue;
        PyObject *where = PyObject_GetAttrString(value, "__module__");
        int here = where && PyUnicode_Check(where) &&
                   PyUnicode_Compare(where, own_name) == 0;
        Py_XDECREF(where);
        PyErr_Clear();
        if (here && PyObject_HasAttrString(value, "do_step")) {
            found = value;
            count++;
        }
    }
    Py_XDECREF(own_name);
    Py_DECREF(module);
    if (count != 1) {
        PyErr_Format(PyExc_TypeError, "module %s defines %d slave classes (classes with a "
                     "do_step method), not one", module_name, count);
        return NULL;
    }
    Py_INCREF(found);
    return found;
}

/* After an import error at instantiation (logged by failed()): name the FMU's requirement
   list and the Python that lacks it, and how to run the FMU with another. */
static void missing_packages(Instance *inst, const char *resources)
{
    PyObject *executable = PySys_GetObject("executable"); /* borrowed */
    const char *python = executable && PyUnicode_Check(executable)
                             ? PyUnicode_AsUTF8(executable) : NULL;
    PyErr_Clear();
    emitf(inst, inst->fmi3 ? (int)fmi3Fatal : (int)fmi2Fatal, "logStatusFatal",
          "the Python that runs this FMU (%s) lacks packages of the FMU's %s/requirements.txt: "
          "install them there (pip install -r %s/requirements.txt), or name a Python that "
          "has them with AGV_COSIM_PYTHON (hosts that are not Python programs; see "
          "docs/using-the-fmus.md)", python && *python ? python : "unknown", resources,
          resources);
}

static Instance *instantiate(int fmi3, const char *name, const char *location, int visible,
                             int logging_on, fmi2CallbackLogger log2,
                             fmi2ComponentEnvironment env2, fmi3LogMessageCallback log3,
                             fmi3InstanceEnvironment env3)
{
    Instance *inst = calloc(1, sizeof *inst);
    if (inst == NULL) return NULL;
    inst->fmi3 = fmi3;
    inst->name = strdup(name ? name : "");
    inst->logging_on = logging_on;
    inst->log2 = log2;
    inst->env2 = env2;
    inst->log3 = log3;
    inst->env3 = env3;
    char *resources = resource_path(location);

    int gil = gil_take(inst);
    int ok = intern_names() && resources != NULL && inst->name != NULL;
    if (ok) {
        inst->cls = slave_class(resources);
        inst->kwargs = inst->cls ? Py_BuildValue("{s:s,s:s,s:O}", "instance_name", inst->name,
                                                 "resources", resources, "visible",
                                                 visible ? Py_True : Py_False)
                                 : NULL;
        ok = inst->kwargs != NULL && make_slave(inst) == 0;
    }
    if (!ok) {
        if (PyErr_Occurred()) {
            int import_error = PyErr_ExceptionMatches(PyExc_ImportError);
            failed(inst, "instantiation");
            if (import_error) missing_packages(inst, resources);
        } else emit(inst, fmi3 ? (int)fmi3Fatal : (int)fmi2Fatal, "logStatusFatal",
                  "instantiation failed: out of memory");
        drop_slave(inst);
        Py_CLEAR(inst->cls);
        Py_CLEAR(inst->kwargs);
        drop_slots(inst);
        gil_give(gil);
        free(resources);
        free(inst->name);
        free(inst);
        return NULL;
    }
    flush_log(inst);
    gil_give(gil);
    free(resources);
    return inst;
}

static void free_instance(Instance *inst)
{
    if (inst == NULL) return;
    int gil = gil_take(inst);
    drop_slave(inst);
    Py_CLEAR(inst->cls);
    Py_CLEAR(inst->kwargs);
    drop_slots(inst);
    gil_give(gil);
    free(inst->name);
    free(inst);
}

/* Call method() without arguments under the GIL; the FMI status. */
static int simple_call(Instance *inst, PyObject *method, const char *what)
{
    int gil = gil_take(inst);
    PyObject *result = call0(method);
    int status = OK_STATUS(inst);
    if (result == NULL) status = failed(inst, what);
    else {
        Py_DECREF(result);
        flush_log(inst);
    }
    gil_give(gil);
    return status;
}

static int setup(Instance *inst, double start, const char *what)
{
    PyObject *time = PyFloat_FromDouble(start);
    PyObject *result = time ? call1(inst->setup_experiment, time) : NULL;
    Py_XDECREF(time);
    if (result == NULL) return failed(inst, what);
    Py_DECREF(result);
    return OK_STATUS(inst);
}

static int reset(Instance *inst, const char *what)
{
    int refused = not_in(inst, MODES_ALIVE, what);
    if (refused) return refused;
    int gil = gil_take(inst);
    drop_slave(inst);
    inst->terminated = 0;
    int status = make_slave(inst) == 0 ? OK_STATUS(inst) : failed(inst, what);
    if (status == OK_STATUS(inst)) flush_log(inst);
    gil_give(gil);
    return settle(inst, status);
}

/* do_step(t, h): 1 for a true result, 0 for false, -1 on an exception; for FMI 3.0 a
   result's status and terminateSimulation attributes when it has them. */
/* What SlaveLogic.do_step does (see _fmi_step_access); 1, or -1 with an exception. */
static int fast_step(Instance *inst, PyObject *t, PyObject *h, double end)
{
    PyObject *done = call2(inst->advance, t, h);
    if (done == NULL) return hook_failed(inst, s_step_failed, t);
    Py_DECREF(done);
    PyObject *time = PyFloat_FromDouble(end);
    if (time == NULL) return -1;
    int failed_set = PyObject_SetAttr(inst->slave, s_time, time);
    Py_DECREF(time);
    if (failed_set < 0) return hook_failed(inst, s_step_failed, t);
    PyObject *lazy = PyObject_GetAttr(inst->slave, s_lazy_step);
    if (lazy == NULL) return -1;
    int is_lazy = PyObject_IsTrue(lazy);
    Py_DECREF(lazy);
    if (is_lazy < 0) return -1;
    if (is_lazy) return PyObject_SetAttr(inst->slave, s_stale, Py_True) < 0 ? -1 : 1;
    done = call0(inst->publish);
    if (done == NULL) return hook_failed(inst, s_step_failed, t);
    Py_DECREF(done);
    return PyObject_SetAttr(inst->slave, s_stale, Py_False) < 0 ? -1 : 1;
}

static int step(Instance *inst, double t, double h, int *status, int *terminate)
{
    PyObject *a = PyFloat_FromDouble(t), *b = PyFloat_FromDouble(h);
    if (inst->advance != NULL && a && b) {
        *status = -1;
        *terminate = 0;
        int done = fast_step(inst, a, b, t + h);
        Py_DECREF(a);
        Py_DECREF(b);
        if (done > 0) flush_log(inst);
        return done;
    }
    PyObject *result = (a && b) ? call2(inst->do_step, a, b) : NULL;
    Py_XDECREF(a);
    Py_XDECREF(b);
    if (result == NULL) return -1;
    *status = -1;
    *terminate = 0;
    int truth;
    if (inst->fmi3 && PyObject_HasAttr(result, s_status)) {
        PyObject *value = PyObject_GetAttr(result, s_status);
        long code = value ? PyLong_AsLong(value) : -1;
        Py_XDECREF(value);
        PyObject *stop = PyObject_GetAttr(result, s_terminate_simulation);
        *terminate = stop ? PyObject_IsTrue(stop) == 1 : 0;
        Py_XDECREF(stop);
        PyErr_Clear();
        *status = code < 0 ? (int)fmi3Error : (int)code;
        truth = *status == (int)fmi3OK;
    } else {
        truth = PyObject_IsTrue(result);
    }
    Py_DECREF(result);
    if (truth < 0) return -1;
    flush_log(inst);
    return truth;
}

static int state_get(Instance *inst, void **state, const char *what)
{
    int refused = not_in(inst, MODES_ALIVE, what);
    if (refused) return refused;
    int gil = gil_take(inst);
    int status = OK_STATUS(inst);
    PyObject *result = PyObject_CallMethod(inst->slave, "_get_fmu_state", NULL);
    if (result == NULL) status = failed(inst, what);
    else {
        Py_XDECREF((PyObject *)*state); /* an earlier state the host passes back to reuse */
        *state = result;
        flush_log(inst);
    }
    gil_give(gil);
    return settle(inst, status);
}

static int state_set(Instance *inst, void *state, const char *what)
{
    int refused = not_in(inst, MODES_ALIVE, what);
    if (refused) return refused;
    if (state == NULL) return refuse(inst, what, "no FMU state given");
    int gil = gil_take(inst);
    int status = OK_STATUS(inst);
    PyObject *result = PyObject_CallMethod(inst->slave, "_set_fmu_state", "O",
                                           (PyObject *)state);
    if (result == NULL) status = failed(inst, what);
    else {
        Py_DECREF(result);
        flush_log(inst);
        inst->mode = saved_mode((PyObject *)state);
    }
    gil_give(gil);
    return settle(inst, status);
}

static int state_free(Instance *inst, void **state)
{
    if (state == NULL || *state == NULL) return OK_STATUS(inst);
    int gil = gil_take(inst);
    Py_DECREF((PyObject *)*state);
    *state = NULL;
    gil_give(gil);
    return OK_STATUS(inst);
}

/* The serialised state (bytes, new reference) or NULL with a Python exception. */
static PyObject *state_bytes(Instance *inst, void *state)
{
    if (state == NULL) {
        PyErr_SetString(PyExc_ValueError, "no FMU state given");
        return NULL;
    }
    PyObject *bytes = PyObject_CallMethod(inst->cls, "_fmu_state_to_bytes", "O",
                                          (PyObject *)state);
    if (bytes != NULL && !PyBytes_Check(bytes)) {
        Py_DECREF(bytes);
        PyErr_SetString(PyExc_TypeError, "_fmu_state_to_bytes must return bytes");
        return NULL;
    }
    return bytes;
}

static int state_size(Instance *inst, void *state, size_t *size, const char *what)
{
    int refused = not_in(inst, MODES_ALIVE, what);
    if (refused) return refused;
    int gil = gil_take(inst);
    int status = OK_STATUS(inst);
    PyObject *bytes = state_bytes(inst, state);
    if (bytes == NULL) status = failed(inst, what);
    else {
        *size = (size_t)PyBytes_GET_SIZE(bytes);
        Py_DECREF(bytes);
    }
    gil_give(gil);
    return settle(inst, status);
}

static int state_serialize(Instance *inst, void *state, char *out, size_t size,
                           const char *what)
{
    int refused = not_in(inst, MODES_ALIVE, what);
    if (refused) return refused;
    int gil = gil_take(inst);
    int status = OK_STATUS(inst);
    PyObject *bytes = state_bytes(inst, state);
    if (bytes == NULL) status = failed(inst, what);
    else if ((size_t)PyBytes_GET_SIZE(bytes) > size) {
        emitf(inst, ERROR_STATUS(inst), "logStatusError", "%s: the buffer holds %zu bytes, "
              "the state needs %zd", what, size, PyBytes_GET_SIZE(bytes));
        status = ERROR_STATUS(inst);
    } else {
        memcpy(out, PyBytes_AS_STRING(bytes), (size_t)PyBytes_GET_SIZE(bytes));
    }
    Py_XDECREF(bytes);
    gil_give(gil);
    return settle(inst, status);
}

static int state_deserialize(Instance *inst, const char *in, size_t size, void **state,
                             const char *what)
{
    int refused = not_in(inst, MODES_ALIVE, what);
    if (refused) return refused;
    int gil = gil_take(inst);
    int status = OK_STATUS(inst);
    PyObject *result = PyObject_CallMethod(inst->cls, "_fmu_state_from_bytes", "y#", in,
                                           (Py_ssize_t)size);
    if (result == NULL) status = failed(inst, what);
    else {
        Py_XDECREF((PyObject *)*state);
        *state = result;
    }
    gil_give(gil);
    return settle(inst, status);
}

/* A get or set under the GIL: body returns 0 or -1 (Python exception). */
#define VALUES_CALL(inst, what, body)                                                    \
    do {                                                                                  \
        if (n == 0) return OK_STATUS(inst);                                               \
        int gil_ = gil_take(inst);                                                        \
        int status_ = OK_STATUS(inst);                                                    \
        if ((body) < 0) status_ = settle(inst, failed(inst, what));                       \
        else if (inst->log_queue && PyList_GET_SIZE(inst->log_queue)) flush_log(inst);    \
        gil_give(gil_);                                                                   \
        return status_;                                                                   \
    } while (0)

static int unsupported(Instance *inst, const char *function)
{
    emitf(inst, ERROR_STATUS(inst), "logStatusError", "%s is not supported by this FMU",
          function);
    return settle(inst, ERROR_STATUS(inst));
}

/* 1 when `token` is the GUID / instantiation token the FMU was built with (or it names
   none); else 0 and the reason in `why`. */
static int token_matches(const char *token, const char *location, const char *what,
                         const char *argument, char *why, size_t size)
{
    char *resources = resource_path(location);
    char *own = resources ? built_token(resources) : NULL;
    free(resources);
    if (own == NULL) {
        snprintf(why, size, "%s: out of memory", what);
        return 0;
    }
    int same = own[0] == '\0' || (token != NULL && strcmp(token, own) == 0);
    if (!same)
        snprintf(why, size, "%s: refused: %s \"%s\" is not this FMU's (\"%s\", in its "
                 "modelDescription.xml): the host read another FMU's model description, or "
                 "this FMU was rebuilt since", what, argument, token ? token : "(null)", own);
    free(own);
    return same;
}

/* ================================================================== FMI 2.0 */
#define I2 ((Instance *)c)

fmi2Component EXPORT2(fmi2Instantiate)(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    fmi2CallbackLogger logger = functions ? functions->logger : NULL;
    void *env = functions ? functions->componentEnvironment : NULL;
    if (fmuType != fmi2CoSimulation) {
        if (logger) logger(env, instanceName, fmi2Error, "logStatusError",
                           "this FMU supports co-simulation only");
        return NULL;
    }
    char why[512];
    if (!token_matches(fmuGUID, fmuResourceLocation, "fmi2Instantiate", "fmuGUID", why,
                       sizeof why)) {
        if (logger) logger(env, instanceName, fmi2Error, "logStatusError", "%s", why);
        return NULL;
    }
    return instantiate(0, instanceName, fmuResourceLocation, visible, loggingOn, logger, env,
                       NULL, NULL);
}

void EXPORT2(fmi2FreeInstance)(fmi2Component c) { free_instance(I2); }

fmi2Status EXPORT2(fmi2SetDebugLogging)(fmi2Component c, fmi2Boolean loggingOn, size_t n,
                               const fmi2String categories[])
{
    (void)n;
    (void)categories;
    I2->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Status EXPORT2(fmi2SetupExperiment)(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    int refused = not_in(I2, MODE_INSTANTIATED, "fmi2SetupExperiment");
    if (refused) return (fmi2Status)refused;
    if (!isfinite(startTime))
        return (fmi2Status)refuse(I2, "fmi2SetupExperiment", "the start time is not finite");
    int gil = gil_take(I2);
    int status = setup(I2, startTime, "fmi2SetupExperiment");
    if (status == fmi2OK) flush_log(I2);
    gil_give(gil);
    return (fmi2Status)settle(I2, status);
}

fmi2Status EXPORT2(fmi2EnterInitializationMode)(fmi2Component c)
{
    int refused = not_in(I2, MODE_INSTANTIATED, "fmi2EnterInitializationMode");
    if (refused) return (fmi2Status)refused;
    return (fmi2Status)moved(I2, simple_call(I2, I2->enter_init, "fmi2EnterInitializationMode"),
                             MODE_INITIALIZATION);
}

fmi2Status EXPORT2(fmi2ExitInitializationMode)(fmi2Component c)
{
    int refused = not_in(I2, MODE_INITIALIZATION, "fmi2ExitInitializationMode");
    if (refused) return (fmi2Status)refused;
    return (fmi2Status)moved(I2, simple_call(I2, I2->exit_init, "fmi2ExitInitializationMode"),
                             MODE_STEP);
}

fmi2Status EXPORT2(fmi2Terminate)(fmi2Component c)
{
    int refused = not_in(I2, MODE_STEP | MODE_STEP_FAILED, "fmi2Terminate");
    if (refused) return (fmi2Status)refused;
    return (fmi2Status)moved(I2, simple_call(I2, I2->terminate, "fmi2Terminate"),
                             MODE_TERMINATED);
}

fmi2Status EXPORT2(fmi2Reset)(fmi2Component c) { return (fmi2Status)reset(I2, "fmi2Reset"); }

fmi2Status EXPORT2(fmi2GetReal)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       fmi2Real value[])
{
    CHECK_VALUES(I2, "fmi2GetReal", 0, REAL);
    VALUES_CALL(I2, "fmi2GetReal", get_reals(I2, vr, n, value));
}

fmi2Status EXPORT2(fmi2SetReal)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       const fmi2Real value[])
{
    CHECK_VALUES(I2, "fmi2SetReal", 1, REAL);
    VALUES_CALL(I2, "fmi2SetReal", set_reals(I2, vr, n, value));
}

fmi2Status EXPORT2(fmi2GetInteger)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Integer value[])
{
    CHECK_VALUES(I2, "fmi2GetInteger", 0, INTEGER);
    VALUES_CALL(I2, "fmi2GetInteger", get_ints(I2, vr, n, value));
}

fmi2Status EXPORT2(fmi2SetInteger)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Integer value[])
{
    CHECK_VALUES(I2, "fmi2SetInteger", 1, INTEGER);
    VALUES_CALL(I2, "fmi2SetInteger", set_ints(I2, vr, n, value));
}

fmi2Status EXPORT2(fmi2GetBoolean)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Boolean value[])
{
    CHECK_VALUES(I2, "fmi2GetBoolean", 0, BOOLEAN);
    VALUES_CALL(I2, "fmi2GetBoolean", get_bools(I2, vr, n, value, 1));
}

fmi2Status EXPORT2(fmi2SetBoolean)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Boolean value[])
{
    CHECK_VALUES(I2, "fmi2SetBoolean", 1, BOOLEAN);
    VALUES_CALL(I2, "fmi2SetBoolean", set_bools(I2, vr, n, value, 1));
}

fmi2Status EXPORT2(fmi2GetString)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                         fmi2String value[])
{
    CHECK_VALUES(I2, "fmi2GetString", 0, STRING);
    VALUES_CALL(I2, "fmi2GetString", get_strings(I2, vr, n, value));
}

fmi2Status EXPORT2(fmi2SetString)(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                         const fmi2String value[])
{
    CHECK_VALUES(I2, "fmi2SetString", 1, STRING);
    VALUES_CALL(I2, "fmi2SetString", set_strings(I2, vr, n, value));
}

fmi2Status EXPORT2(fmi2GetFMUstate)(fmi2Component c, fmi2FMUstate *state)
{
    return (fmi2Status)state_get(I2, state, "fmi2GetFMUstate");
}

fmi2Status EXPORT2(fmi2SetFMUstate)(fmi2Component c, fmi2FMUstate state)
{
    return (fmi2Status)state_set(I2, state, "fmi2SetFMUstate");
}

fmi2Status EXPORT2(fmi2FreeFMUstate)(fmi2Component c, fmi2FMUstate *state)
{
    return (fmi2Status)state_free(I2, state);
}

fmi2Status EXPORT2(fmi2SerializedFMUstateSize)(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    return (fmi2Status)state_size(I2, state, size, "fmi2SerializedFMUstateSize");
}

fmi2Status EXPORT2(fmi2SerializeFMUstate)(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size)
{
    return (fmi2Status)state_serialize(I2, state, bytes, size, "fmi2SerializeFMUstate");
}

fmi2Status EXPORT2(fmi2DeSerializeFMUstate)(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state)
{
    return (fmi2Status)state_deserialize(I2, bytes, size, state, "fmi2DeSerializeFMUstate");
}

fmi2Status EXPORT2(fmi2GetDirectionalDerivative)(fmi2Component c, const fmi2ValueReference vu[],
                                        size_t nu, const fmi2ValueReference vk[], size_t nk,
                                        const fmi2Real dk[], fmi2Real dv[])
{
    (void)vu, (void)nu, (void)vk, (void)nk, (void)dk, (void)dv;
    return (fmi2Status)unsupported(I2, "fmi2GetDirectionalDerivative");
}

fmi2Status EXPORT2(fmi2SetRealInputDerivatives)(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t n, const fmi2Integer order[],
                                       const fmi2Real value[])
{
    (void)vr, (void)n, (void)order, (void)value;
    return (fmi2Status)unsupported(I2, "fmi2SetRealInputDerivatives");
}

fmi2Status EXPORT2(fmi2GetRealOutputDerivatives)(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t n, const fmi2Integer order[],
                                        fmi2Real value[])
{
    (void)vr, (void)n, (void)order, (void)value;
    return (fmi2Status)unsupported(I2, "fmi2GetRealOutputDerivatives");
}

fmi2Status EXPORT2(fmi2DoStep)(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePrior)
{
    (void)noSetFMUStatePrior;
    int refused = check_step(I2, "fmi2DoStep", t, h);
    if (refused) return (fmi2Status)refused;
    int gil = gil_take(I2);
    int code, terminate;
    int done = step(I2, t, h, &code, &terminate);
    fmi2Status status = fmi2OK;
    if (done < 0) {
        status = (fmi2Status)failed(I2, "fmi2DoStep");
    } else if (done) {
        I2->last_successful_time = t + h;
    } else {
        I2->last_successful_time = t;
        I2->terminated = 1;
        status = fmi2Discard;
        I2->mode = MODE_STEP_FAILED;
    }
    gil_give(gil);
    return (fmi2Status)settle(I2, status);
}

fmi2Status EXPORT2(fmi2CancelStep)(fmi2Component c)
{
    return (fmi2Status)unsupported(I2, "fmi2CancelStep");
}

fmi2Status EXPORT2(fmi2GetStatus)(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    int refused = not_in(I2, MODES_STATUS, "fmi2GetStatus");
    if (refused) return (fmi2Status)refused;
    if (s == fmi2DoStepStatus) {
        *value = fmi2OK; /* steps are never asynchronous */
        return fmi2OK;
    }
    return (fmi2Status)unsupported(I2, "fmi2GetStatus for this status kind");
}

fmi2Status EXPORT2(fmi2GetRealStatus)(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    int refused = not_in(I2, MODES_STATUS, "fmi2GetRealStatus");
    if (refused) return (fmi2Status)refused;
    if (s == fmi2LastSuccessfulTime) {
        *value = I2->last_successful_time;
        return fmi2OK;
    }
    return (fmi2Status)unsupported(I2, "fmi2GetRealStatus for this status kind");
}

fmi2Status EXPORT2(fmi2GetIntegerStatus)(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    int refused = not_in(I2, MODES_STATUS, "fmi2GetIntegerStatus");
    if (refused) return (fmi2Status)refused;
    (void)s, (void)value;
    return (fmi2Status)unsupported(I2, "fmi2GetIntegerStatus");
}

fmi2Status EXPORT2(fmi2GetBooleanStatus)(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    int refused = not_in(I2, MODES_STATUS, "fmi2GetBooleanStatus");
    if (refused) return (fmi2Status)refused;
    if (s == fmi2Terminated) {
        *value = I2->terminated ? fmi2True : fmi2False;
        return fmi2OK;
    }
    return (fmi2Status)unsupported(I2, "fmi2GetBooleanStatus for this status kind");
}

fmi2Status EXPORT2(fmi2GetStringStatus)(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    int refused = not_in(I2, MODES_STATUS, "fmi2GetStringStatus");
    if (refused) return (fmi2Status)refused;
    (void)s, (void)value;
    return (fmi2Status)unsupported(I2, "fmi2GetStringStatus");
}

/* ================================================================== FMI 3.0 */
#define I3 ((Instance *)instance)

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)earlyReturnAllowed, (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables, (void)intermediateUpdate;
    if (eventModeUsed) {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                                   "this FMU has no event mode");
        return NULL;
    }
    char why[512];
    if (!token_matches(instantiationToken, resourcePath, "fmi3InstantiateCoSimulation",
                       "instantiationToken", why, sizeof why)) {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError", why);
        return NULL;
    }
    return instantiate(1, instanceName, resourcePath, visible, loggingOn, NULL, NULL,
                       logMessage, instanceEnvironment);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName,
                                          fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible;
    (void)loggingOn;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "this FMU supports co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { free_instance(I3); }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn,
                               size_t nCategories, const fmi3String categories[])
{
    (void)nCategories, (void)categories;
    I3->logging_on = loggingOn;
    return fmi3OK;
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    int refused = not_in(I3, MODE_INSTANTIATED, "fmi3EnterInitializationMode");
    if (refused) return (fmi3Status)refused;
    if (!isfinite(startTime))
        return (fmi3Status)refuse(I3, "fmi3EnterInitializationMode", "the start time is not "
                                  "finite");
    int gil = gil_take(I3);
    int status = setup(I3, startTime, "fmi3EnterInitializationMode");
    gil_give(gil);
    if (status != fmi3OK) return (fmi3Status)settle(I3, status);
    return (fmi3Status)moved(I3, simple_call(I3, I3->enter_init, "fmi3EnterInitializationMode"),
                             MODE_INITIALIZATION);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    int refused = not_in(I3, MODE_INITIALIZATION, "fmi3ExitInitializationMode");
    if (refused) return (fmi3Status)refused;
    return (fmi3Status)moved(I3, simple_call(I3, I3->exit_init, "fmi3ExitInitializationMode"),
                             MODE_STEP);
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    /* FMI 3.0: Event Mode -> Step Mode only; this FMU has no event mode, it is in step
       mode right after fmi3ExitInitializationMode */
    return (fmi3Status)refuse(I3, "fmi3EnterStepMode", "this FMU has no event mode (it is "
                              "in step mode after fmi3ExitInitializationMode)");
}

fmi3Status fmi3Terminate(fmi3Instance instance)
{
    int refused = not_in(I3, MODE_STEP | MODE_STEP_FAILED, "fmi3Terminate");
    if (refused) return (fmi3Status)refused;
    return (fmi3Status)moved(I3, simple_call(I3, I3->terminate, "fmi3Terminate"),
                             MODE_TERMINATED);
}

fmi3Status fmi3Reset(fmi3Instance instance) { return (fmi3Status)reset(I3, "fmi3Reset"); }

#define N_VALUES_MATCH(what)                                                             \
    if (nValues != n) {                                                                   \
        emitf(I3, fmi3Error, "logStatusError", "%s: %zu values for %zu value references "  \
              "(arrays are not supported)", what, nValues, n);                             \
        return (fmi3Status)settle(I3, fmi3Error);                                         \
    }

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                          fmi3Float64 values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3GetFloat64")
    CHECK_VALUES(I3, "fmi3GetFloat64", 0, REAL);
    VALUES_CALL(I3, "fmi3GetFloat64", get_reals(I3, vr, n, values));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                          const fmi3Float64 values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3SetFloat64")
    CHECK_VALUES(I3, "fmi3SetFloat64", 1, REAL);
    VALUES_CALL(I3, "fmi3SetFloat64", set_reals(I3, vr, n, values));
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                        fmi3Int32 values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3GetInt32")
    CHECK_VALUES(I3, "fmi3GetInt32", 0, INTEGER);
    VALUES_CALL(I3, "fmi3GetInt32", get_ints(I3, vr, n, values));
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                        const fmi3Int32 values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3SetInt32")
    CHECK_VALUES(I3, "fmi3SetInt32", 1, INTEGER);
    VALUES_CALL(I3, "fmi3SetInt32", set_ints(I3, vr, n, values));
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                          fmi3Boolean values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3GetBoolean")
    CHECK_VALUES(I3, "fmi3GetBoolean", 0, BOOLEAN);
    VALUES_CALL(I3, "fmi3GetBoolean", get_bools(I3, vr, n, values, 0));
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                          const fmi3Boolean values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3SetBoolean")
    CHECK_VALUES(I3, "fmi3SetBoolean", 1, BOOLEAN);
    VALUES_CALL(I3, "fmi3SetBoolean", set_bools(I3, vr, n, values, 0));
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                         fmi3String values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3GetString")
    CHECK_VALUES(I3, "fmi3GetString", 0, STRING);
    VALUES_CALL(I3, "fmi3GetString", get_strings(I3, vr, n, values));
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                         const fmi3String values[], size_t nValues)
{
    N_VALUES_MATCH("fmi3SetString")
    CHECK_VALUES(I3, "fmi3SetString", 1, STRING);
    VALUES_CALL(I3, "fmi3SetString", set_strings(I3, vr, n, values));
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *state)
{
    return (fmi3Status)state_get(I3, state, "fmi3GetFMUState");
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState state)
{
    return (fmi3Status)state_set(I3, state, "fmi3SetFMUState");
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *state)
{
    return (fmi3Status)state_free(I3, state);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState state, size_t *size)
{
    return (fmi3Status)state_size(I3, state, size, "fmi3SerializedFMUStateSize");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState state,
                                 fmi3Byte serializedState[], size_t size)
{
    return (fmi3Status)state_serialize(I3, state, (char *)serializedState, size,
                                       "fmi3SerializeFMUState");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *state)
{
    return (fmi3Status)state_deserialize(I3, (const char *)serializedState, size, state,
                                         "fmi3DeserializeFMUState");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 t, fmi3Float64 h,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    int refused = check_step(I3, "fmi3DoStep", t, h);
    if (refused) {
        if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
        if (earlyReturn) *earlyReturn = fmi3False;
        if (terminateSimulation) *terminateSimulation = fmi3False;
        if (lastSuccessfulTime) *lastSuccessfulTime = t;
        return (fmi3Status)refused;
    }
    int gil = gil_take(I3);
    int code, terminate;
    int done = step(I3, t, h, &code, &terminate);
    fmi3Status status;
    if (done < 0) {
        status = (fmi3Status)failed(I3, "fmi3DoStep");
        terminate = 0;
    } else if (code >= 0) {
        status = (fmi3Status)code;
    } else {
        status = done ? fmi3OK : fmi3Discard;
    }
    if (status == fmi3Discard) I3->mode = MODE_STEP_FAILED;
    settle(I3, (int)status);
    gil_give(gil);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (terminateSimulation) *terminateSimulation = terminate ? fmi3True : fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = status == fmi3OK ? t + h : t;
    return status;
}

/* Every other FMI 3.0 function: the loader calls this with the instance and the name. */
fmi3Status agv_fmi3Unsupported(fmi3Instance instance, const char *function)
{
    if (instance == NULL) return fmi3Error;
    return (fmi3Status)unsupported(I3, function);
}
