/*
 * A threaded FMI 2.0 co-simulation host in plain C (test support, no Python in it): it
 * steps instances of one FMU from a pool of worker threads, as libcosim does.
 *
 *   fmi2_threads UNZIPDIR MODEL_IDENTIFIER GUID STOP STEP OUT_VRS INSTANCES THREADS MODE
 *                [VR=VALUE ...]
 *
 * Loads UNZIPDIR/binaries/linux64/MODEL_IDENTIFIER.so with dlopen (RTLD_LOCAL) and starts
 * THREADS worker threads. In rounds (all workers start a round together and the next
 * round starts when all have finished it), worker j handles the instances k with
 * (k + round) % THREADS == j, one after the other, so every instance moves from thread
 * to thread, and several instances run on several threads at once:
 *  - round 0: instantiate, set up, set the Real inputs/parameters VR=VALUE * (1 + 0.1 k)
 *    in initialisation mode (instance k), exit initialisation mode, read the outputs;
 *  - rounds 1 ... n: one step on fmpy's time grid (t_k = k STEP, h = t_k+1 - t_k), read
 *    the outputs;
 *  - MODE "pool": a last round terminates and frees every instance on a worker other
 *    than the one that created it (when THREADS > 1), then the workers exit;
 *    MODE "exit-first": the workers exit first, then the main thread terminates and
 *    frees every instance.
 * Prints "k t v1 v2 ..." per instance and communication point (the Reals OUT_VRS, comma
 * separated value references) with %.17g, as fmi2_host does, then on stderr the page
 * faults of the workers in the step rounds after the first and the number of FMI calls
 * in them ("worker page faults F in C FMI calls ..."), and returns 0; a failing call
 * prints its status and returns 1.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>

#include "fmi2FunctionTypes.h"

#define MAX_OUT 64

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s] status %d %s: ", instance ? instance : "", (int)status,
            category ? category : "");
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

static fmi2InstantiateTYPE *instantiate_fn;
static fmi2FreeInstanceTYPE *freeinstance_fn;
static fmi2SetupExperimentTYPE *setupexperiment_fn;
static fmi2EnterInitializationModeTYPE *enterinitializationmode_fn;
static fmi2ExitInitializationModeTYPE *exitinitializationmode_fn;
static fmi2SetRealTYPE *setreal_fn;
static fmi2GetRealTYPE *getreal_fn;
static fmi2DoStepTYPE *dostep_fn;
static fmi2TerminateTYPE *terminate_fn;

enum { INIT, STEP, FREE, QUIT };

static const char *guid;
static char resources[4200];
static double stop, step;
static long n_steps;
static fmi2ValueReference outputs[MAX_OUT];
static size_t n_outputs;
static int n_settings;
static fmi2ValueReference *setting_vr;
static double *setting_value;
static int n_instances, n_threads;
static fmi2Component *instances;
static double *table; /* [instance][row][output] */
static fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

static pthread_barrier_t start_barrier, done_barrier;
static int phase;
static long round_;
static int failures;
static long step_faults, step_calls; /* page faults of the workers in the step rounds */
static pthread_mutex_t failure_lock = PTHREAD_MUTEX_INITIALIZER;

static void fail(const char *call, int k, int status)
{
    pthread_mutex_lock(&failure_lock);
    fprintf(stderr, "instance %d: %s returned status %d\n", k, call, status);
    failures++;
    pthread_mutex_unlock(&failure_lock);
}

#define CHECK(call, k)                                                                    \
    do {                                                                                  \
        fmi2Status status_ = (call);                                                      \
        if (status_ > fmi2Warning) {                                                      \
            fail(#call, k, (int)status_);                                                 \
            return;                                                                       \
        }                                                                                 \
    } while (0)

static void record(int k, long row)
{
    fmi2Status status = getreal_fn(instances[k], outputs, n_outputs,
                                     table + ((size_t)k * (n_steps + 1) + row) * n_outputs);
    if (status > fmi2Warning) fail("fmi2GetReal", k, (int)status);
}

static void initialise(int k)
{
    char name[32];
    snprintf(name, sizeof name, "host%d", k);
    instances[k] = instantiate_fn(name, fmi2CoSimulation, guid, resources, &callbacks,
                                   fmi2False, fmi2True);
    if (instances[k] == NULL) {
        fail("fmi2Instantiate", k, -1);
        return;
    }
    fmi2Component c = instances[k];
    CHECK(setupexperiment_fn(c, fmi2False, 0.0, 0.0, fmi2True, stop), k);
    CHECK(enterinitializationmode_fn(c), k);
    for (int i = 0; i < n_settings; i++) {
        fmi2Real value = setting_value[i] * (1 + 0.1 * k);
        CHECK(setreal_fn(c, &setting_vr[i], 1, &value), k);
    }
    CHECK(exitinitializationmode_fn(c), k);
    record(k, 0);
}

static void advance(int k, long r)
{
    if (instances[k] == NULL) return;
    double t = (r - 1) * step;
    CHECK(dostep_fn(instances[k], t, r * step - t, fmi2True), k);
    record(k, r);
}

static void finish(int k)
{
    if (instances[k] == NULL) return;
    CHECK(terminate_fn(instances[k]), k);
    freeinstance_fn(instances[k]);
    instances[k] = NULL;
}

static void *worker(void *arg)
{
    int j = (int)(size_t)arg;
    for (;;) {
        pthread_barrier_wait(&start_barrier);
        if (phase == QUIT) break;
        struct rusage before, after;
        getrusage(RUSAGE_THREAD, &before);
        long calls = 0;
        for (int k = 0; k < n_instances; k++) {
            if ((k + round_) % n_threads != j) continue;
            if (phase == INIT) initialise(k);
            else if (phase == STEP) advance(k, round_), calls += 2;
            else finish(k);
        }
        getrusage(RUSAGE_THREAD, &after);
        if (phase == STEP && round_ > 1) { /* the first step round warms up */
            pthread_mutex_lock(&failure_lock);
            step_faults += (after.ru_minflt - before.ru_minflt) +
                           (after.ru_majflt - before.ru_majflt);
            step_calls += calls;
            pthread_mutex_unlock(&failure_lock);
        }
        pthread_barrier_wait(&done_barrier);
    }
    return NULL;
}

static void run_round(int what, long r)
{
    phase = what;
    round_ = r;
    pthread_barrier_wait(&start_barrier);
    if (what != QUIT) pthread_barrier_wait(&done_barrier);
}

#define LOAD(pointer, name)                                                              \
    pointer = (name##TYPE *)dlsym(library, #name);                                        \
    if (pointer == NULL) {                                                                \
        fprintf(stderr, "missing %s\n", #name);                                           \
        return 1;                                                                         \
    }

int main(int argc, char **argv)
{
    if (argc < 10) {
        fprintf(stderr, "usage: %s UNZIPDIR ID GUID STOP STEP OUT_VRS INSTANCES THREADS MODE "
                "[VR=VALUE ...]\n", argv[0]);
        return 2;
    }
    const char *unzipdir = argv[1], *identifier = argv[2], *mode = argv[9];
    guid = argv[3];
    stop = atof(argv[4]);
    step = atof(argv[5]);
    n_steps = (long)(stop / step + 0.5);
    for (char *token = strtok(argv[6], ","); token && n_outputs < MAX_OUT;
         token = strtok(NULL, ","))
        outputs[n_outputs++] = (fmi2ValueReference)strtoul(token, NULL, 10);
    n_instances = atoi(argv[7]);
    n_threads = atoi(argv[8]);
    int exit_first = strcmp(mode, "exit-first") == 0;
    if (n_instances < 1 || n_threads < 1 || (!exit_first && strcmp(mode, "pool") != 0)) {
        fprintf(stderr, "bad INSTANCES, THREADS or MODE\n");
        return 2;
    }
    n_settings = argc - 10;
    setting_vr = calloc((size_t)n_settings + 1, sizeof *setting_vr);
    setting_value = calloc((size_t)n_settings + 1, sizeof *setting_value);
    for (int i = 0; i < n_settings; i++) {
        const char *equals = strchr(argv[10 + i], '=');
        if (equals == NULL) {
            fprintf(stderr, "bad VR=VALUE: %s\n", argv[10 + i]);
            return 2;
        }
        setting_vr[i] = (fmi2ValueReference)strtoul(argv[10 + i], NULL, 10);
        setting_value[i] = strtod(equals + 1, NULL);
    }
    instances = calloc((size_t)n_instances, sizeof *instances);
    table = calloc((size_t)n_instances * (n_steps + 1) * (n_outputs ? n_outputs : 1),
                   sizeof *table);

    char path[4096];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", unzipdir, identifier);
    snprintf(resources, sizeof resources, "file://%s/resources", unzipdir);
    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (library == NULL) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 1;
    }
    LOAD(instantiate_fn, fmi2Instantiate)
    LOAD(freeinstance_fn, fmi2FreeInstance)
    LOAD(setupexperiment_fn, fmi2SetupExperiment)
    LOAD(enterinitializationmode_fn, fmi2EnterInitializationMode)
    LOAD(exitinitializationmode_fn, fmi2ExitInitializationMode)
    LOAD(setreal_fn, fmi2SetReal)
    LOAD(getreal_fn, fmi2GetReal)
    LOAD(dostep_fn, fmi2DoStep)
    LOAD(terminate_fn, fmi2Terminate)

    pthread_barrier_init(&start_barrier, NULL, (unsigned)n_threads + 1);
    pthread_barrier_init(&done_barrier, NULL, (unsigned)n_threads + 1);
    pthread_t *threads = calloc((size_t)n_threads, sizeof *threads);
    for (int j = 0; j < n_threads; j++)
        pthread_create(&threads[j], NULL, worker, (void *)(size_t)j);

    run_round(INIT, 0);
    for (long r = 1; r <= n_steps && failures == 0; r++) run_round(STEP, r);
    if (!exit_first) run_round(FREE, n_steps + 1);
    run_round(QUIT, 0);
    for (int j = 0; j < n_threads; j++) pthread_join(threads[j], NULL);
    if (exit_first) {
        for (int k = 0; k < n_instances; k++) {
            if (instances[k] == NULL) continue;
            fmi2Status status = terminate_fn(instances[k]);
            if (status > fmi2Warning) fail("fmi2Terminate", k, (int)status);
            freeinstance_fn(instances[k]);
        }
    }
    if (failures) return 1;
    fprintf(stderr, "worker page faults %ld in %ld FMI calls of the step rounds after the first\n",
            step_faults, step_calls);

    for (int k = 0; k < n_instances; k++) {
        for (long row = 0; row <= n_steps; row++) {
            printf("%d %.17g", k, row * step);
            const double *values = table + ((size_t)k * (n_steps + 1) + row) * n_outputs;
            for (size_t i = 0; i < n_outputs; i++) printf(" %.17g", values[i]);
            printf("\n");
        }
    }
    free(threads);
    dlclose(library);
    return 0;
}
