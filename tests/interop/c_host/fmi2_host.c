/*
 * A minimal FMI 2.0 co-simulation host in plain C (test support, no Python in it).
 *
 *   fmi2_host UNZIPDIR MODEL_IDENTIFIER GUID STOP STEP OUT_VRS [VR=VALUE ...]
 *
 * Loads UNZIPDIR/binaries/linux64/MODEL_IDENTIFIER.so with dlopen (RTLD_LOCAL, as FMI
 * tools do), instantiates it, sets the Real inputs/parameters VR=VALUE in initialisation
 * mode, steps from 0 to STOP on fmpy's time grid and prints "t v1 v2 ..." per
 * communication point (the Reals OUT_VRS, comma separated value references) with %.17g.
 * Frees the instance, unloads the library and returns 0; a failing call prints its
 * status and returns 1.
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

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

#define CHECK(call)                                                                      \
    do {                                                                                  \
        fmi2Status status_ = (call);                                                      \
        if (status_ > fmi2Warning) {                                                      \
            fprintf(stderr, "%s returned status %d\n", #call, (int)status_);              \
            return 1;                                                                     \
        }                                                                                 \
    } while (0)

#define LOAD(name)                                                                       \
    name##TYPE *name = (name##TYPE *)dlsym(library, #name);                               \
    if (name == NULL) {                                                                   \
        fprintf(stderr, "missing %s\n", #name);                                           \
        return 1;                                                                         \
    }

int main(int argc, char **argv)
{
    if (argc < 7) {
        fprintf(stderr, "usage: %s UNZIPDIR ID GUID STOP STEP OUT_VRS [VR=VALUE ...]\n", argv[0]);
        return 2;
    }
    const char *unzipdir = argv[1], *identifier = argv[2], *guid = argv[3];
    double stop = atof(argv[4]), step = atof(argv[5]);

    fmi2ValueReference outputs[64];
    size_t n_outputs = 0;
    for (char *token = strtok(argv[6], ","); token && n_outputs < 64; token = strtok(NULL, ","))
        outputs[n_outputs++] = (fmi2ValueReference)strtoul(token, NULL, 10);

    char path[4096], resources[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", unzipdir, identifier);
    snprintf(resources, sizeof resources, "file://%s/resources", unzipdir);

    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (library == NULL) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 1;
    }
    LOAD(fmi2Instantiate) LOAD(fmi2FreeInstance) LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode) LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal)
    LOAD(fmi2GetReal) LOAD(fmi2DoStep) LOAD(fmi2Terminate)

    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, guid, resources, &callbacks,
                                      fmi2False, fmi2True);
    if (c == NULL) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        dlclose(library);
        return 1;
    }
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2True, stop));
    CHECK(fmi2EnterInitializationMode(c));
    for (int k = 7; k < argc; k++) {
        fmi2ValueReference vr = (fmi2ValueReference)strtoul(argv[k], NULL, 10);
        const char *equals = strchr(argv[k], '=');
        if (equals == NULL) {
            fprintf(stderr, "bad VR=VALUE: %s\n", argv[k]);
            return 2;
        }
        fmi2Real value = strtod(equals + 1, NULL);
        CHECK(fmi2SetReal(c, &vr, 1, &value));
    }
    CHECK(fmi2ExitInitializationMode(c));

    fmi2Real values[64];
    long n_steps = (long)(stop / step + 0.5);
    /* the communication points of fmpy.simulate_fmu: t_k = k STEP, h = t_k+1 - t_k */
    for (long k = 0; k <= n_steps; k++) {
        double t = k * step;
        CHECK(fmi2GetReal(c, outputs, n_outputs, values));
        printf("%.17g", t);
        for (size_t i = 0; i < n_outputs; i++) printf(" %.17g", values[i]);
        printf("\n");
        if (k < n_steps) CHECK(fmi2DoStep(c, t, (k + 1) * step - t, fmi2True));
    }
    CHECK(fmi2Terminate(c));
    fmi2FreeInstance(c);
    dlclose(library);
    return 0;
}
