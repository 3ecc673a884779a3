/*
 * A plain FMI 2.0 co-simulation host in C for benchmarks/bench_c_host.py: steps the FMUs
 * of one run in the master's Gauss-Seidel order, with no Python of its own.
 *
 *   c_host_loop SCHEDULE ROWS_OUT
 *
 * SCHEDULE (written by bench_c_host.py from the run's plan), one item a line:
 *   grid BASE SLOPE DEN STEP STEPS START STOP EVERY   t_k = (BASE + SLOPE k) / DEN
 *   fmu UNZIPDIR IDENTIFIER GUID NAME                 in the master's model order
 *   param I KIND VR VALUE                            KIND r (hex double), i, b, s
 *                                                     (set before initialisation)
 *   out I N VR...                                    the Reals read from FMU I
 *   in I N (VR SRC POS)...                           the Reals set, from out buffers
 *   pre I ONCE                                       read at the start of each pass
 *   order I                                          the pass order
 *   record SRC POS                                   a recorded value
 * The master's sequence: setup experiment, parameters, enter and exit initialisation
 * (every FMU, in order), a pass at START, the first row, then per macro step every FMU's
 * doStep, a pass, and a row every EVERY steps and at the last. Each status is checked; no
 * NaN check. Rows (t, values) go to ROWS_OUT as raw doubles; stdout gets
 * "cpu_per_step_us STEPS" measured from the first row to the last
 * (CLOCK_PROCESS_CPUTIME_ID).
 */
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "fmi2Functions.h"

#define MAX_FMUS 32
#define MAX_VARS 64

typedef struct {
    fmi2Component c;
    fmi2GetRealTYPE *get;
    fmi2SetRealTYPE *set;
    fmi2DoStepTYPE *step;
    fmi2ValueReference out_vr[MAX_VARS];
    double out[MAX_VARS];
    size_t n_out;
    fmi2ValueReference in_vr[MAX_VARS];
    double in[MAX_VARS];
    int in_src[MAX_VARS], in_pos[MAX_VARS];
    size_t n_in;
    int once;
    void *library;
} Fmu;

static Fmu fmus[MAX_FMUS];

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    (void)category;
    if (status < fmi2Error)
        return;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s] status %d: ", instance ? instance : "", (int)status);
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

#define CHECK(call)                                                                      \
    do {                                                                                  \
        fmi2Status status_ = (call);                                                      \
        if (status_ > fmi2Warning) {                                                      \
            fprintf(stderr, "%s returned status %d\n", #call, (int)status_);              \
            exit(1);                                                                      \
        }                                                                                 \
    } while (0)

static void *symbol(void *library, const char *name)
{
    void *found = dlsym(library, name);
    if (found == NULL) {
        fprintf(stderr, "missing %s\n", name);
        exit(1);
    }
    return found;
}

static void get(Fmu *f)
{
    if (f->n_out)
        CHECK(f->get(f->c, f->out_vr, f->n_out, f->out));
}

static void set(Fmu *f)
{
    if (!f->n_in)
        return;
    for (size_t j = 0; j < f->n_in; j++)
        f->in[j] = fmus[f->in_src[j]].out[f->in_pos[j]];
    CHECK(f->set(f->c, f->in_vr, f->n_in, f->in));
}

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

static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s SCHEDULE ROWS_OUT\n", argv[0]);
        return 2;
    }
    FILE *in = fopen(argv[1], "r");
    FILE *rows = fopen(argv[2], "wb");
    if (in == NULL || rows == NULL) {
        perror("open");
        return 2;
    }
    long long base = 0, slope = 0, den = 1, steps = 0, every = 1;
    double step = 0, start = 0, stop = 0;
    int n_fmus = 0, pre[MAX_FMUS], n_pre = 0, order[MAX_FMUS], n_order = 0;
    int rec_src[MAX_VARS], rec_pos[MAX_VARS], n_rec = 0;
    char word[64];
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    while (fscanf(in, "%63s", word) == 1) {
        if (!strcmp(word, "grid")) {
            if (fscanf(in, "%lld %lld %lld %la %lld %la %la %lld", &base, &slope, &den, &step,
                       &steps, &start, &stop, &every) != 8)
                return 2;
        } else if (!strcmp(word, "fmu")) {
            char dir[2048], id[256], guid[256], name[256], path[4096], resources[4200];
            if (n_fmus == MAX_FMUS ||
                fscanf(in, "%2047s %255s %255s %255s", dir, id, guid, name) != 4)
                return 2;
            snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", dir, id);
            snprintf(resources, sizeof resources, "file://%s/resources", dir);
            void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
            if (library == NULL) {
                fprintf(stderr, "dlopen: %s\n", dlerror());
                return 1;
            }
            Fmu *f = &fmus[n_fmus++];
            fmi2InstantiateTYPE *instantiate = symbol(library, "fmi2Instantiate");
            f->get = symbol(library, "fmi2GetReal");
            f->set = symbol(library, "fmi2SetReal");
            f->step = symbol(library, "fmi2DoStep");
            f->c = instantiate(name, fmi2CoSimulation, guid, resources, &callbacks, fmi2False,
                               fmi2True);
            if (f->c == NULL) {
                fprintf(stderr, "fmi2Instantiate %s failed\n", name);
                return 1;
            }
            fmi2SetupExperimentTYPE *setup = symbol(library, "fmi2SetupExperiment");
            CHECK(setup(f->c, fmi2False, 0.0, start, fmi2True, stop));
            f->library = library;  /* kept: the FMU stays loaded until exit */
        } else if (!strcmp(word, "param")) {
            int i;
            char kind[4];
            fmi2ValueReference vr;
            if (fscanf(in, "%d %3s %u", &i, kind, &vr) != 3 || i < 0 || i >= n_fmus)
                return 2;
            void *library = fmus[i].library;
            if (kind[0] == 'r') {
                double v;
                if (fscanf(in, "%la", &v) != 1)
                    return 2;
                CHECK(fmus[i].set(fmus[i].c, &vr, 1, &v));
            } else if (kind[0] == 'i' || kind[0] == 'b') {
                int v;
                if (fscanf(in, "%d", &v) != 1)
                    return 2;
                fmi2SetIntegerTYPE *seti = symbol(library, kind[0] == 'i' ? "fmi2SetInteger"
                                                                           : "fmi2SetBoolean");
                CHECK(seti(fmus[i].c, &vr, 1, &v));
            } else {
                char v[4096];
                if (fscanf(in, "%4095s", v) != 1)
                    return 2;
                fmi2String s = v;
                fmi2SetStringTYPE *sets = symbol(library, "fmi2SetString");
                CHECK(sets(fmus[i].c, &vr, 1, &s));
            }
        } else if (!strcmp(word, "out") || !strcmp(word, "in")) {
            int i, n;
            if (fscanf(in, "%d %d", &i, &n) != 2 || i < 0 || i >= n_fmus || n < 0 ||
                n > MAX_VARS)
                return 2;
            Fmu *f = &fmus[i];
            for (int j = 0; j < n; j++) {
                if (word[0] == 'o') {
                    if (fscanf(in, "%u", &f->out_vr[j]) != 1)
                        return 2;
                } else if (fscanf(in, "%u %d %d", &f->in_vr[j], &f->in_src[j],
                                  &f->in_pos[j]) != 3) {
                    return 2;
                }
            }
            if (word[0] == 'o')
                f->n_out = (size_t)n;
            else
                f->n_in = (size_t)n;
        } else if (!strcmp(word, "pre")) {
            int i, once;
            if (fscanf(in, "%d %d", &i, &once) != 2 || n_pre == MAX_FMUS)
                return 2;
            pre[n_pre++] = i;
            fmus[i].once = once;
        } else if (!strcmp(word, "order")) {
            if (n_order == MAX_FMUS || fscanf(in, "%d", &order[n_order]) != 1)
                return 2;
            n_order++;
        } else if (!strcmp(word, "record")) {
            if (n_rec == MAX_VARS || fscanf(in, "%d %d", &rec_src[n_rec], &rec_pos[n_rec]) != 2)
                return 2;
            n_rec++;
        } else {
            fprintf(stderr, "unknown item %s\n", word);
            return 2;
        }
    }
    /* initialisation: enter (every FMU, after its parameters), then exit */
    for (int i = 0; i < n_fmus; i++) {
        fmi2EnterInitializationModeTYPE *enter = symbol(fmus[i].library,
                                                        "fmi2EnterInitializationMode");
        CHECK(enter(fmus[i].c));
    }
    for (int i = 0; i < n_fmus; i++) {
        fmi2ExitInitializationModeTYPE *leave = symbol(fmus[i].library,
                                                       "fmi2ExitInitializationMode");
        CHECK(leave(fmus[i].c));
    }
    double row[1 + MAX_VARS], cpu_first = 0.0;
    for (long long k = 0; k <= steps; k++) {
        double t = (double)(base + slope * k) / (double)den;
        if (k > 0) {
            double t_prev = (double)(base + slope * (k - 1)) / (double)den;
            double h = t_prev + step == t ? step : reaching(t_prev, t);
            for (int i = 0; i < n_fmus; i++)
                CHECK(fmus[i].step(fmus[i].c, t_prev, h, fmi2True));
        }
        /* the Gauss-Seidel pass at t: the units read first (a read-once unit is not read
           again in the order) */
        for (int p = 0; p < n_pre; p++)
            get(&fmus[pre[p]]);
        for (int p = 0; p < n_order; p++) {
            Fmu *f = &fmus[order[p]];
            set(f);
            if (!f->once)
                get(f);
        }
        if (k % every == 0 || k == steps) {
            row[0] = t;
            for (int r = 0; r < n_rec; r++)
                row[1 + r] = fmus[rec_src[r]].out[rec_pos[r]];
            fwrite(row, sizeof(double), (size_t)(1 + n_rec), rows);
            if (k == 0)
                cpu_first = cpu_now();
        }
    }
    double cpu = cpu_now() - cpu_first;
    fclose(rows);
    printf("%.6f %lld\n", cpu / (double)steps * 1e6, steps);
    fflush(stdout);
    _exit(0);  /* the FMUs' Python is left as the master leaves it: not timed */
}
