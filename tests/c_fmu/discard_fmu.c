/* A minimal FMI 2.0 co-simulation FMU for the orchestrator's tests (written for agv-cosim).
 *
 * One output y = current time [s] (value reference 0) and one fixed parameter
 * discard_time [s] (value reference 1, start 0.3). fmi2DoStep from t returns fmi2Discard
 * once t + h passes discard_time (by more than 1e-9 s), without asking to terminate:
 * fmi2GetBooleanStatus(fmi2Terminated) answers false and fmi2LastSuccessfulTime is t.
 * Such a Discard is an error for the master (the FMU neither stepped nor asked to stop).
 * Every other FMI 2.0 co-simulation function exists; the ones a fixed-step master
 * never needs return fmi2Error.
 */
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

typedef struct {
    double time, discard_time, last_successful;
    const fmi2CallbackFunctions *callbacks;
    char *name;
} Instance;

#define UNUSED(x) (void)(x)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n,
                               const fmi2String categories[]) {
    UNUSED(c); UNUSED(on); UNUSED(n); UNUSED(categories);
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String resources, const fmi2CallbackFunctions *callbacks,
                              fmi2Boolean visible, fmi2Boolean logging) {
    UNUSED(resources); UNUSED(visible); UNUSED(logging);
    if (type != fmi2CoSimulation || !guid || strcmp(guid, "{agv-test-c-discard-1}") != 0)
        return NULL;
    Instance *inst = calloc(1, sizeof(Instance));
    if (!inst) return NULL;
    inst->discard_time = 0.3;
    inst->callbacks = callbacks;
    inst->name = strdup(name ? name : "");
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = c;
    if (!inst) return;
    free(inst->name);
    free(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    UNUSED(toleranceDefined); UNUSED(tolerance); UNUSED(stopTimeDefined); UNUSED(stopTime);
    Instance *inst = c;
    inst->time = inst->last_successful = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { UNUSED(c); return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { UNUSED(c); return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { UNUSED(c); return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { UNUSED(c); return fmi2Error; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *inst = c;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] == 0) value[i] = inst->time;
        else if (vr[i] == 1) value[i] = inst->discard_time;
        else return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *inst = c;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] == 1) inst->discard_time = value[i];
        else return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(value);
    return nvr ? fmi2Error : fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(value);
    return nvr ? fmi2Error : fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(value);
    return nvr ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(value);
    return nvr ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(value);
    return nvr ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(value);
    return nvr ? fmi2Error : fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) {
    UNUSED(c); UNUSED(s); return fmi2Error;
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) {
    UNUSED(c); UNUSED(s); return fmi2Error;
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) {
    UNUSED(c); UNUSED(s); return fmi2Error;
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    UNUSED(c); UNUSED(s); UNUSED(n); return fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    UNUSED(c); UNUSED(s); UNUSED(b); UNUSED(n); return fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n,
                                   fmi2FMUstate *s) {
    UNUSED(c); UNUSED(b); UNUSED(n); UNUSED(s); return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[],
                                        size_t nu, const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real dv[], fmi2Real dz[]) {
    UNUSED(c); UNUSED(u); UNUSED(nu); UNUSED(z); UNUSED(nz); UNUSED(dv); UNUSED(dz);
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(nvr); UNUSED(order); UNUSED(value); return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    UNUSED(c); UNUSED(vr); UNUSED(nvr); UNUSED(order); UNUSED(value); return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    UNUSED(noSetPrior);
    Instance *inst = c;
    if (t + h > inst->discard_time + 1e-9) {
        if (inst->callbacks && inst->callbacks->logger)
            inst->callbacks->logger(inst->callbacks->componentEnvironment, inst->name,
                                    fmi2Discard, "logStatusDiscard",
                                    "step refused (no termination requested)");
        return fmi2Discard;
    }
    inst->time = t + h;
    inst->last_successful = inst->time;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { UNUSED(c); return fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    UNUSED(c); UNUSED(k); UNUSED(v); return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    Instance *inst = c;
    if (k != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = inst->last_successful;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    UNUSED(c); UNUSED(k); UNUSED(v); return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    UNUSED(c);
    if (k != fmi2Terminated) return fmi2Discard;
    *v = fmi2False;  /* the point of this FMU: a Discard without a stop request */
    return fmi2OK;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    UNUSED(c); UNUSED(k); UNUSED(v); return fmi2Discard;
}
