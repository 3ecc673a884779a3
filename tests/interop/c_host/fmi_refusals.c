/*
 * A plain C host (test support, no Python in it) that makes the calls FMI forbids and
 * checks that the FMU refuses each with the status FMI asks for.
 *
 *   fmi_refusals 2 UNZIPDIR MODEL_IDENTIFIER GUID INPUT_VR OUTPUT_VR FIXED_VR
 *   fmi_refusals 3 UNZIPDIR MODEL_IDENTIFIER TOKEN INPUT_VR OUTPUT_VR FIXED_VR
 *
 * Loads UNZIPDIR/binaries/<platform>/MODEL_IDENTIFIER.so with dlopen (RTLD_LOCAL) and
 * runs each case on a fresh instance (INPUT_VR a Real input, OUTPUT_VR a Real output,
 * FIXED_VR a fixed Real parameter). Prints one line per check,
 *   check CASE CALL: status S expected E ok|WRONG
 * and the FMU's log messages on stderr (the test reads the reasons there). Every case
 * also makes allowed calls (the positive controls: a step of 0.1 s, setting the fixed
 * parameter before initialisation, restoring an untouched state). Returns 0 when every
 * status is the expected one, 1 otherwise, 2 on bad arguments.
 */
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

static int wrong = 0;
static const char *current = "";

static void expect(const char *call, int status, int expected)
{
    printf("check %s %s: status %d expected %d %s\n", current, call, status, expected,
           status == expected ? "ok" : "WRONG");
    if (status != expected) wrong++;
}

static void logger2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                    fmi2String category, fmi2String message, ...)
{
    (void)env, (void)instance;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s] status %d %s: ", current, (int)status, category ? category : "");
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                    fmi3String message)
{
    (void)env;
    fprintf(stderr, "[%s] status %d %s: %s\n", current, (int)status, category ? category : "",
            message ? message : "");
}

#define LOAD(name)                                                                       \
    name##TYPE *name = (name##TYPE *)dlsym(library, #name);                               \
    if (name == NULL) {                                                                   \
        fprintf(stderr, "missing %s\n", #name);                                           \
        return 1;                                                                         \
    }

/* ------------------------------------------------------------------ FMI 2.0 */
static int fmi2_cases(void *library, const char *resources, const char *guid,
                      fmi2ValueReference input, fmi2ValueReference output,
                      fmi2ValueReference fixed)
{
    LOAD(fmi2Instantiate) LOAD(fmi2FreeInstance) LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode) LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal)
    LOAD(fmi2GetReal) LOAD(fmi2DoStep) LOAD(fmi2Terminate) LOAD(fmi2Reset)
    LOAD(fmi2GetFMUstate) LOAD(fmi2SetFMUstate) LOAD(fmi2FreeFMUstate)
    LOAD(fmi2SerializedFMUstateSize) LOAD(fmi2SerializeFMUstate) LOAD(fmi2DeSerializeFMUstate)

    fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    fmi2Component c;
    fmi2Real value;

#define FRESH()                                                                          \
    c = fmi2Instantiate("host", fmi2CoSimulation, guid, resources, &callbacks, fmi2False,  \
                        fmi2True);                                                        \
    if (c == NULL) {                                                                      \
        fprintf(stderr, "fmi2Instantiate failed in %s\n", current);                       \
        return 1;                                                                         \
    }
#define READY()                                                                          \
    FRESH()                                                                               \
    expect("fmi2SetupExperiment", fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0), 0); \
    expect("fmi2EnterInitializationMode", fmi2EnterInitializationMode(c), 0);             \
    expect("fmi2ExitInitializationMode", fmi2ExitInitializationMode(c), 0);

    current = "wrong_guid";
    c = fmi2Instantiate("host", fmi2CoSimulation, "{not-this-fmu}", resources, &callbacks,
                        fmi2False, fmi2True);
    expect("fmi2Instantiate returned NULL", c == NULL, 1);
    if (c != NULL) fmi2FreeInstance(c);

    current = "negative_step";
    READY()
    expect("fmi2DoStep(0, -0.1)", fmi2DoStep(c, 0.0, -0.1, fmi2True), fmi2Error);
    fmi2FreeInstance(c);

    current = "zero_step";
    READY()
    expect("fmi2DoStep(0, 0)", fmi2DoStep(c, 0.0, 0.0, fmi2True), fmi2Error);
    fmi2FreeInstance(c);

    current = "nan_step";
    READY()
    expect("fmi2DoStep(0, nan)", fmi2DoStep(c, 0.0, NAN, fmi2True), fmi2Error);
    fmi2FreeInstance(c);

    current = "step_before_initialisation";
    FRESH()
    expect("fmi2DoStep(0, 0.1)", fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2Error);
    fmi2FreeInstance(c);

    current = "step_after_terminate";
    READY()
    expect("fmi2DoStep(0, 0.1)", fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2OK);
    expect("fmi2Terminate", fmi2Terminate(c), fmi2OK);
    expect("fmi2DoStep(0.1, 0.1)", fmi2DoStep(c, 0.1, 0.1, fmi2True), fmi2Error);
    expect("fmi2Reset", fmi2Reset(c), fmi2OK);
    expect("fmi2SetupExperiment", fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0), 0);
    expect("fmi2EnterInitializationMode", fmi2EnterInitializationMode(c), 0);
    expect("fmi2ExitInitializationMode", fmi2ExitInitializationMode(c), 0);
    expect("fmi2DoStep(0, 0.1) after fmi2Reset", fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2OK);
    fmi2FreeInstance(c);

    current = "exit_initialisation_twice";
    READY()
    expect("fmi2ExitInitializationMode", fmi2ExitInitializationMode(c), fmi2Error);
    fmi2FreeInstance(c);

    current = "set_output";
    READY()
    value = 1.0;
    expect("fmi2SetReal(output)", fmi2SetReal(c, &output, 1, &value), fmi2Error);
    fmi2FreeInstance(c);

    current = "set_fixed_parameter";
    FRESH()
    value = 0.5;
    expect("fmi2SetReal(fixed) before initialisation", fmi2SetReal(c, &fixed, 1, &value),
           fmi2OK);
    expect("fmi2SetupExperiment", fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0), 0);
    expect("fmi2EnterInitializationMode", fmi2EnterInitializationMode(c), 0);
    expect("fmi2ExitInitializationMode", fmi2ExitInitializationMode(c), 0);
    value = 3.0;
    expect("fmi2SetReal(fixed) in step mode", fmi2SetReal(c, &fixed, 1, &value), fmi2Error);
    value = -1.0;
    expect("fmi2GetReal(fixed)", fmi2GetReal(c, &fixed, 1, &value), fmi2OK);
    expect("fixed parameter kept 0.5", value == 0.5, 1);
    fmi2FreeInstance(c);

    current = "nan_input";
    READY()
    value = NAN;
    expect("fmi2SetReal(input, nan)", fmi2SetReal(c, &input, 1, &value), fmi2Error);
    fmi2FreeInstance(c);

    current = "inf_input";
    READY()
    value = -INFINITY;
    expect("fmi2SetReal(input, -inf)", fmi2SetReal(c, &input, 1, &value), fmi2Error);
    value = 1.0;
    expect("fmi2GetReal(input)", fmi2GetReal(c, &input, 1, &value), fmi2OK);
    expect("input kept its value", isfinite(value), 1);
    fmi2FreeInstance(c);

    current = "foreign_state";
    READY()
    expect("fmi2DoStep(0, 0.1)", fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2OK);
    fmi2FMUstate state = NULL, good = NULL, bad = NULL;
    size_t size = 0;
    expect("fmi2GetFMUstate", fmi2GetFMUstate(c, &state), fmi2OK);
    expect("fmi2SerializedFMUstateSize", fmi2SerializedFMUstateSize(c, state, &size), fmi2OK);
    char *bytes = calloc(size + 64, 1), *tampered = calloc(size + 64, 1);
    expect("fmi2SerializeFMUstate", fmi2SerializeFMUstate(c, state, bytes, size), fmi2OK);
    expect("fmi2DeSerializeFMUstate", fmi2DeSerializeFMUstate(c, bytes, size, &good), fmi2OK);
    expect("fmi2SetFMUstate(its own state)", fmi2SetFMUstate(c, good), fmi2OK);
    /* the same JSON object with one key more */
    snprintf(tampered, size + 64, "{\"unknown\": 1, %s", bytes + 1);
    expect("fmi2DeSerializeFMUstate(tampered)",
           fmi2DeSerializeFMUstate(c, tampered, strlen(tampered), &bad), fmi2OK);
    expect("fmi2SetFMUstate(unknown key)", fmi2SetFMUstate(c, bad), fmi2Error);
    expect("fmi2SetFMUstate(its own state) after the error", fmi2SetFMUstate(c, good),
           fmi2OK);
    expect("fmi2DoStep(0.1, 0.1) after the restore", fmi2DoStep(c, 0.1, 0.1, fmi2True),
           fmi2OK);
    fmi2FreeFMUstate(c, &state);
    fmi2FreeFMUstate(c, &good);
    fmi2FreeFMUstate(c, &bad);
    free(bytes);
    free(tampered);
    fmi2FreeInstance(c);
    return 0;
}

/* ------------------------------------------------------------------ FMI 3.0 */
static int fmi3_cases(void *library, const char *resources, const char *token,
                      fmi3ValueReference input, fmi3ValueReference output,
                      fmi3ValueReference fixed)
{
    LOAD(fmi3InstantiateCoSimulation) LOAD(fmi3FreeInstance) LOAD(fmi3EnterInitializationMode)
    LOAD(fmi3ExitInitializationMode) LOAD(fmi3SetFloat64) LOAD(fmi3DoStep) LOAD(fmi3Terminate)

    fmi3Instance c;
    fmi3Float64 value;
    fmi3Boolean event, stop, early;
    fmi3Float64 last;

#define FRESH3(tok)                                                                      \
    fmi3InstantiateCoSimulation("host", tok, resources, fmi3False, fmi3True, fmi3False,    \
                                fmi3False, NULL, 0, NULL, logger3, NULL)
#define READY3()                                                                         \
    c = FRESH3(token);                                                                    \
    if (c == NULL) {                                                                      \
        fprintf(stderr, "fmi3InstantiateCoSimulation failed in %s\n", current);           \
        return 1;                                                                         \
    }                                                                                     \
    expect("fmi3EnterInitializationMode",                                                 \
           fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3False, 0), 0);             \
    expect("fmi3ExitInitializationMode", fmi3ExitInitializationMode(c), 0);
#define STEP3(t, h) fmi3DoStep(c, t, h, fmi3True, &event, &stop, &early, &last)

    current = "wrong_guid";
    c = FRESH3("{not-this-fmu}");
    expect("fmi3InstantiateCoSimulation returned NULL", c == NULL, 1);
    if (c != NULL) fmi3FreeInstance(c);

    current = "negative_step";
    READY3()
    expect("fmi3DoStep(0, -0.1)", STEP3(0.0, -0.1), fmi3Error);
    fmi3FreeInstance(c);

    current = "step_after_terminate";
    READY3()
    expect("fmi3DoStep(0, 0.1)", STEP3(0.0, 0.1), fmi3OK);
    expect("fmi3Terminate", fmi3Terminate(c), fmi3OK);
    expect("fmi3DoStep(0.1, 0.1)", STEP3(0.1, 0.1), fmi3Error);
    fmi3FreeInstance(c);

    current = "set_output";
    READY3()
    value = 1.0;
    expect("fmi3SetFloat64(output)", fmi3SetFloat64(c, &output, 1, &value, 1), fmi3Error);
    fmi3FreeInstance(c);

    current = "set_fixed_parameter";
    READY3()
    value = 3.0;
    expect("fmi3SetFloat64(fixed) in step mode", fmi3SetFloat64(c, &fixed, 1, &value, 1),
           fmi3Error);
    fmi3FreeInstance(c);

    current = "nan_input";
    READY3()
    value = NAN;
    expect("fmi3SetFloat64(input, nan)", fmi3SetFloat64(c, &input, 1, &value, 1), fmi3Error);
    fmi3FreeInstance(c);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 8 || (strcmp(argv[1], "2") != 0 && strcmp(argv[1], "3") != 0)) {
        fprintf(stderr, "usage: %s 2|3 UNZIPDIR ID GUID INPUT_VR OUTPUT_VR FIXED_VR\n",
                argv[0]);
        return 2;
    }
    int fmi3 = argv[1][0] == '3';
    const char *unzipdir = argv[2], *identifier = argv[3], *guid = argv[4];
    unsigned int input = (unsigned int)strtoul(argv[5], NULL, 10);
    unsigned int output = (unsigned int)strtoul(argv[6], NULL, 10);
    unsigned int fixed = (unsigned int)strtoul(argv[7], NULL, 10);

    char path[4096], resources[4200];
    snprintf(path, sizeof path, "%s/binaries/%s/%s.so", unzipdir,
             fmi3 ? "x86_64-linux" : "linux64", identifier);
    if (fmi3) snprintf(resources, sizeof resources, "%s/resources/", unzipdir);
    else snprintf(resources, sizeof resources, "file://%s/resources", unzipdir);

    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (library == NULL) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 1;
    }
    int failed = fmi3 ? fmi3_cases(library, resources, guid, input, output, fixed)
                      : fmi2_cases(library, resources, guid, input, output, fixed);
    dlclose(library);
    return failed || wrong ? 1 : 0;
}
