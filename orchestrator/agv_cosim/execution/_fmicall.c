/*
 * _fmicall: the master's FMI calls without ctypes (agv_cosim.execution.compiled builds
 * this file with gcc and loads it; without it the master calls through ctypes).
 *
 * A Program is a list of operations prepared once per run from the units' buffers:
 * write the track, copy an input value from its source buffer, call an FMI get / set
 * (FMI 2.0 or 3.0 argument lists), call a Python function (a table's fill), call
 * fmi2DoStep / fmi3DoStep, check a buffer of floats. Calling the Program runs them in order with the GIL held,
 * exactly the calls, arguments and checks of the generated Python functions of
 * agv_cosim/execution/fastpath.py:
 *   - a get / set / fill status above 1 raises the exception fail(name, status) returns;
 *   - after a checked get, a float output that is not finite calls check(unit, t)
 *     (which raises, naming the output);
 *   - a doStep status above 1 (FMI 3.0: or terminateSimulation) calls
 *     the op's stepped(unit, status, requests), which records a stop request or raises.
 *   program(t) for a pass, program(t, h) for a step.
 *
 * run_stretch(step, exchanges, grid, k0, k1, requests, track) runs the macro steps
 * k0 .. k1-1 of a run in C: t_k from the grid, the step program, the time in the track,
 * then (unless requests is no longer empty) each (phase, program) of the exchange. It
 * returns the number of macro steps completed with their exchange; a macro step after
 * which an FMU asked to stop has no exchange and is not counted.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

typedef int (*get2_t)(void *, const unsigned int *, size_t, void *);
typedef int (*get3_t)(void *, const unsigned int *, size_t, void *, size_t);
typedef int (*step2_t)(void *, double, double, int);
typedef int (*step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);

enum { OP_TRACK = 0, OP_TIME = 1, OP_COPY = 2, OP_CALL2 = 3, OP_CALL3 = 4, OP_PY = 5,
       OP_STEP2 = 6, OP_STEP3 = 7, OP_CHECK = 8 };

typedef struct {
    int kind;
    int slot;          /* OP_TRACK: track index written */
    double value;      /* OP_TRACK: value written */
    void *fn;          /* the C function */
    void *comp;        /* component / instance */
    void *vrs;         /* value references */
    size_t n;          /* count of value references */
    void *buf;         /* values */
    size_t nvalues;    /* FMI 3.0: count of values */
    double *check;     /* floats checked after the call, or NULL */
    size_t ncheck;
    size_t size;       /* OP_COPY: bytes */
    void *src;         /* OP_COPY: source */
    void *flags[4];    /* OP_STEP3: eventHandlingNeeded, terminate, earlyReturn, last */
    PyObject *name;    /* FMI function name for fail() */
    PyObject *unit;    /* for check() / stepped() */
    PyObject *py;      /* OP_PY: the callable */
} Op;

typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    Op *ops;
    Py_ssize_t nops;
    double *track;      /* the track's doubles, or NULL: then track_seq */
    PyObject *track_seq;
    PyObject *fail;     /* fail(name, status) -> exception */
    PyObject *check;    /* check(unit, t) */
    PyObject *requests;
    PyObject *keep;     /* objects whose memory the ops point into */
} Program;

static void *address(PyObject *item, int *error)
{
    if (item == Py_None)
        return NULL;
    void *p = PyLong_AsVoidPtr(item);
    if (p == NULL && PyErr_Occurred())
        *error = 1;
    return p;
}

static int write_track(Program *self, int slot, double value, int as_int)
{
    if (self->track) {
        self->track[slot] = value;
        return 0;
    }
    if (self->track_seq == NULL)
        return 0;
    PyObject *v = as_int ? PyLong_FromDouble(value) : PyFloat_FromDouble(value);
    if (v == NULL)
        return -1;
    int r = PySequence_SetItem(self->track_seq, slot, v);
    Py_DECREF(v);
    return r;
}

static int raise_failed(Program *self, PyObject *name, int status)
{
    PyObject *exc = PyObject_CallFunction(self->fail, "Oi", name, status);
    if (exc == NULL)
        return -1;
    PyErr_SetObject((PyObject *)Py_TYPE(exc), exc);
    Py_DECREF(exc);
    return -1;
}

static int checked(Program *self, Op *op, double t)
{
    size_t i;
    for (i = 0; i < op->ncheck; i++)
        if (!isfinite(op->check[i]))
            break;
    if (i == op->ncheck)
        return 0;
    PyObject *r = PyObject_CallFunction(self->check, "Od", op->unit, t);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}

static int stepped(Program *self, Op *op, int status)
{
    PyObject *r = PyObject_CallFunction(op->py, "OiO", op->unit, status, self->requests);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}

/* Run the program at time t with step h; 0, or -1 with an exception set. */
static int run_program(Program *self, double t, double h)
{
    for (Py_ssize_t i = 0; i < self->nops; i++) {
        Op *op = &self->ops[i];
        int status;
        switch (op->kind) {
        case OP_TRACK:
            if (write_track(self, op->slot, op->value, 1) < 0)
                return -1;
            break;
        case OP_TIME:
            if (write_track(self, op->slot, t, 0) < 0)
                return -1;
            break;
        case OP_COPY:
            memcpy(op->buf, op->src, op->size);
            break;
        case OP_CALL2:
        case OP_CALL3:
            status = op->kind == OP_CALL2
                ? ((get2_t)op->fn)(op->comp, op->vrs, op->n, op->buf)
                : ((get3_t)op->fn)(op->comp, op->vrs, op->n, op->buf, op->nvalues);
            if (PyErr_Occurred())  /* the bridge never leaves one; be safe */
                return -1;
            if (status > 1)
                return raise_failed(self, op->name, status);
            if (op->check && checked(self, op, t) < 0)
                return -1;
            break;
        case OP_PY: {
            PyObject *r = PyObject_CallNoArgs(op->py);
            if (r == NULL)
                return -1;
            status = (int)PyLong_AsLong(r);
            Py_DECREF(r);
            if (status == -1 && PyErr_Occurred())
                return -1;
            if (status > 1)
                return raise_failed(self, op->name, status);
            if (op->check && checked(self, op, t) < 0)
                return -1;
            break;
        }
        case OP_CHECK:
            if (checked(self, op, t) < 0)
                return -1;
            break;
        case OP_STEP2:
            status = ((step2_t)op->fn)(op->comp, t, h, 1);
            if (status > 1 && stepped(self, op, status) < 0)
                return -1;
            break;
        case OP_STEP3:
            status = ((step3_t)op->fn)(op->comp, t, h, true, op->flags[0], op->flags[1],
                                       op->flags[2], op->flags[3]);
            if ((status > 1 || *(bool *)op->flags[1]) && stepped(self, op, status) < 0)
                return -1;
            break;
        }
    }
    return 0;
}

static PyObject *program_vectorcall(PyObject *callable, PyObject *const *args,
                                    size_t nargsf, PyObject *kwnames)
{
    Program *self = (Program *)callable;
    Py_ssize_t nargs = PyVectorcall_NARGS(nargsf);
    double t = 0.0, h = 0.0;
    if (kwnames != NULL || nargs > 2) {
        PyErr_SetString(PyExc_TypeError, "a program takes (t) or (t, h)");
        return NULL;
    }
    if (nargs > 0) {
        t = PyFloat_AsDouble(args[0]);
        if (t == -1.0 && PyErr_Occurred())
            return NULL;
    }
    if (nargs > 1) {
        h = PyFloat_AsDouble(args[1]);
        if (h == -1.0 && PyErr_Occurred())
            return NULL;
    }
    if (run_program(self, t, h) < 0)
        return NULL;
    Py_RETURN_NONE;
}

static int program_traverse(Program *self, visitproc visit, void *arg)
{
    Py_VISIT(self->track_seq);
    Py_VISIT(self->fail);
    Py_VISIT(self->check);
    Py_VISIT(self->requests);
    Py_VISIT(self->keep);
    for (Py_ssize_t i = 0; i < self->nops; i++) {
        Py_VISIT(self->ops[i].name);
        Py_VISIT(self->ops[i].unit);
        Py_VISIT(self->ops[i].py);
    }
    return 0;
}

static int program_clear(Program *self)
{
    Py_CLEAR(self->track_seq);
    Py_CLEAR(self->fail);
    Py_CLEAR(self->check);
    Py_CLEAR(self->requests);
    Py_CLEAR(self->keep);
    for (Py_ssize_t i = 0; i < self->nops; i++) {
        Py_CLEAR(self->ops[i].name);
        Py_CLEAR(self->ops[i].unit);
        Py_CLEAR(self->ops[i].py);
    }
    return 0;
}

static void program_dealloc(Program *self)
{
    PyObject_GC_UnTrack(self);
    program_clear(self);
    PyMem_Free(self->ops);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/*
 * Program(ops, track_address, track, fail, check, requests, keep)
 *
 * ops: a sequence of tuples (kind, slot, value, fn, comp, vrs, n, buf, nvalues, check,
 * ncheck, size, src, flags (4 addresses or None), name, unit, py); py is the callable
 * of OP_PY and the stepped(unit, status, requests) of a doStep; addresses are ints
 * (None: NULL). track_address: the address of the track's three doubles, or None (then
 * track, a sequence, is written item by item).
 */
static PyObject *program_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    PyObject *ops, *track_address, *track, *fail, *check, *requests, *keep;
    if (kwds != NULL && PyDict_GET_SIZE(kwds)) {
        PyErr_SetString(PyExc_TypeError, "Program takes no keyword arguments");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "OOOOOOO", &ops, &track_address, &track, &fail, &check,
                          &requests, &keep))
        return NULL;
    PyObject *seq = PySequence_Fast(ops, "ops must be a sequence");
    if (seq == NULL)
        return NULL;
    Program *self = (Program *)type->tp_alloc(type, 0);
    if (self == NULL) {
        Py_DECREF(seq);
        return NULL;
    }
    self->vectorcall = program_vectorcall;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    self->ops = PyMem_Calloc(n ? (size_t)n : 1, sizeof(Op));
    if (self->ops == NULL) {
        Py_DECREF(seq);
        Py_DECREF(self);
        return PyErr_NoMemory();
    }
    int error = 0;
    self->track = address(track_address, &error);
    if (self->track == NULL) {
        Py_INCREF(track);
        self->track_seq = track;
    }
    Py_INCREF(fail); self->fail = fail;
    Py_INCREF(check); self->check = check;
    Py_INCREF(requests); self->requests = requests;
    Py_INCREF(keep); self->keep = keep;
    for (Py_ssize_t i = 0; i < n && !error; i++) {
        PyObject *item = PySequence_Fast_GET_ITEM(seq, i);
        PyObject *fn, *comp, *vrs, *buf, *chk, *src, *flags, *name, *unit, *py;
        Py_ssize_t nn, nvalues, ncheck, size;
        Op *op = &self->ops[i];
        if (!PyArg_ParseTuple(item, "iidOOOnOnOnnOOOOO", &op->kind, &op->slot, &op->value,
                              &fn, &comp, &vrs, &nn, &buf, &nvalues, &chk, &ncheck, &size,
                              &src, &flags, &name, &unit, &py)) {
            error = 1;
            break;
        }
        self->nops = i + 1;
        if (op->kind < OP_TRACK || op->kind > OP_CHECK || op->slot < 0 || op->slot > 2 ||
            nn < 0 || nvalues < 0 || ncheck < 0 || size < 0) {
            PyErr_SetString(PyExc_ValueError, "bad operation");
            error = 1;
            break;
        }
        op->fn = address(fn, &error);
        op->comp = address(comp, &error);
        op->vrs = address(vrs, &error);
        op->buf = address(buf, &error);
        op->check = address(chk, &error);
        op->src = address(src, &error);
        op->n = (size_t)nn;
        op->nvalues = (size_t)nvalues;
        op->ncheck = (size_t)ncheck;
        op->size = (size_t)size;
        if (flags != Py_None) {
            if (!PyTuple_Check(flags) || PyTuple_GET_SIZE(flags) != 4) {
                PyErr_SetString(PyExc_ValueError, "flags: 4 addresses");
                error = 1;
                break;
            }
            for (int j = 0; j < 4; j++)
                op->flags[j] = address(PyTuple_GET_ITEM(flags, j), &error);
        }
        if (!error && (op->kind == OP_CALL2 || op->kind == OP_CALL3 || op->kind == OP_STEP2
                       || op->kind == OP_STEP3) && op->fn == NULL) {
            PyErr_SetString(PyExc_ValueError, "an FMI call without a function");
            error = 1;
        }
        if (!error && op->kind == OP_STEP3 &&
            (!op->flags[0] || !op->flags[1] || !op->flags[2] || !op->flags[3])) {
            PyErr_SetString(PyExc_ValueError, "fmi3DoStep needs its 4 flag addresses");
            error = 1;
        }
        if (!error && op->kind == OP_CHECK && !op->check) {
            PyErr_SetString(PyExc_ValueError, "a check needs its buffer");
            error = 1;
        }
        if (!error && op->kind == OP_COPY && (!op->buf || !op->src)) {
            PyErr_SetString(PyExc_ValueError, "a copy needs two addresses");
            error = 1;
        }
        Py_INCREF(name); op->name = name;
        Py_INCREF(unit); op->unit = unit;
        Py_INCREF(py); op->py = py;
    }
    Py_DECREF(seq);
    if (error) {
        Py_DECREF(self);
        return NULL;
    }
    return (PyObject *)self;
}

static PyTypeObject ProgramType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "_fmicall.Program",
    .tp_basicsize = sizeof(Program),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_new = program_new,
    .tp_dealloc = (destructor)program_dealloc,
    .tp_traverse = (traverseproc)program_traverse,
    .tp_clear = (inquiry)program_clear,
    .tp_vectorcall_offset = offsetof(Program, vectorcall),
    .tp_call = PyVectorcall_Call,
    .tp_doc = "A prepared sequence of FMI calls: program(t) or program(t, h).",
};

/* The double h > 0 with t + h == t_next (agv_cosim.execution.grid._reaching). */
static double reaching(double t, double t_next)
{
    double h = t_next - t;
    for (int i = 0; i < 64; i++) {
        double reached = t + h;
        if (reached == t_next)
            return h;
        h = nextafter(h, reached < t_next ? INFINITY : -INFINITY);
    }
    return t_next - t;
}

/*
 * run_stretch(step, exchanges, grid, k0, k1, requests) -> steps completed
 *
 * grid: (base, slope, den, step) with t_k = (base + slope k) / den, every integer below
 * 2**53 in magnitude for the k of the run (checked by the caller), so the division of
 * two exact doubles is the correctly rounded quotient Python's int division gives.
 * exchanges: a tuple of (phase, program); each program's own track is written.
 */
static PyObject *run_stretch(PyObject *module, PyObject *args)
{
    (void)module;
    PyObject *step, *exchanges, *requests;
    long long base, slope, den, k0, k1;
    double step_size;
    if (!PyArg_ParseTuple(args, "O!O!(LLLd)LLO!", &ProgramType, &step, &PyTuple_Type,
                          &exchanges, &base, &slope, &den, &step_size, &k0, &k1,
                          &PyList_Type, &requests))
        return NULL;
    Py_ssize_t nex = PyTuple_GET_SIZE(exchanges);
    for (Py_ssize_t j = 0; j < nex; j++) {
        PyObject *pair = PyTuple_GET_ITEM(exchanges, j);
        if (!PyTuple_Check(pair) || PyTuple_GET_SIZE(pair) != 2 ||
            !PyLong_Check(PyTuple_GET_ITEM(pair, 0)) ||
            !PyObject_TypeCheck(PyTuple_GET_ITEM(pair, 1), &ProgramType)) {
            PyErr_SetString(PyExc_TypeError, "exchanges: (phase, Program) pairs");
            return NULL;
        }
    }
    if (den <= 0) {
        PyErr_SetString(PyExc_ValueError, "grid denominator must be positive");
        return NULL;
    }
    Program *stepper = (Program *)step;
    long long k;
    for (k = k0; k < k1; k++) {
        double t = (double)(base + slope * k) / (double)den;
        double t_next = (double)(base + slope * (k + 1)) / (double)den;
        double h = t + step_size == t_next ? step_size : reaching(t, t_next);
        if (run_program(stepper, t, h) < 0)
            return NULL;
        if (write_track(stepper, 2, t_next, 0) < 0)
            return NULL;
        if (PyList_GET_SIZE(requests))
            break;
        for (Py_ssize_t j = 0; j < nex; j++) {
            PyObject *pair = PyTuple_GET_ITEM(exchanges, j);
            Program *program = (Program *)PyTuple_GET_ITEM(pair, 1);
            if (write_track(program, 1, (double)PyLong_AsLong(PyTuple_GET_ITEM(pair, 0)),
                            1) < 0)
                return NULL;
            if (run_program(program, t_next, 0.0) < 0)
                return NULL;
        }
        if (PyErr_CheckSignals() < 0)
            return NULL;
    }
    return PyLong_FromLongLong(k - k0);
}

static PyMethodDef methods[] = {
    {"run_stretch", run_stretch, METH_VARARGS,
     "run_stretch(step, exchanges, (base, slope, den, step), k0, k1, requests) -> steps"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_fmicall", "The master's FMI calls in C.", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__fmicall(void)
{
    if (PyType_Ready(&ProgramType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    Py_INCREF(&ProgramType);
    if (PyModule_AddObject(m, "Program", (PyObject *)&ProgramType) < 0) {
        Py_DECREF(&ProgramType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
