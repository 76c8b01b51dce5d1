/*
 * The native layer of hfdi's FMI 2.0 co-simulation FMUs.
 *
 * Every fmi2 function of the co-simulation interface, written against the
 * FMI 2.0 headers, calling the FMU's Python slave through the CPython C API
 * (hfdi_fmu_core.h, shared with the FMI 3.0 layer hfdi_fmi3.c). The API is
 * resolved at run time (dlsym), never linked: in a Python host (fmpy, a
 * Python master) the interpreter already in the process is used; in any
 * other host the library named in resources/hfdi_fmu_python.txt is loaded
 * and initialized once, under a lock (the first fmi2Instantiate may come
 * from several threads at once). The FMU's Python modules are imported
 * under private names without touching the host's sys.path (fmu/entry.py).
 *
 * Statuses, as FMI 2.0 defines them:
 *   fmi2Error    a refused call (bad argument, value reference, state, an
 *                exception of the slave); the instance is as before the call;
 *   fmi2Discard  a step not taken (doStep returned false), or a status not
 *                provided;
 *   fmi2Fatal    never (it would declare every instance corrupt).
 * fmi2Instantiate returns NULL after one log message when the FMU cannot be
 * loaded (damaged resources, wrong GUID, no Python).
 *
 * Every message reaches the logger as a printf format that prints the text
 * itself: each '%' doubled.
 */
#include "hfdi_fmu_core.h"

#include "fmi2Functions.h"

/* The message as a printf format printing it: every '%' doubled. */
static void emit2(const Instance* inst, int status, const char* category, const char* text)
{
    fmi2CallbackLogger logger = (fmi2CallbackLogger)inst->logger;
    if (!logger) return;
    size_t n = strlen(text), extra = 0;
    for (size_t i = 0; i < n; i++) extra += text[i] == '%';
    char* safe = (char*)malloc(n + extra + 1);
    if (!safe) return;
    char* o = safe;
    for (size_t i = 0; i < n; i++) {
        *o++ = text[i];
        if (text[i] == '%') *o++ = '%';
    }
    *o = '\0';
    logger((fmi2ComponentEnvironment)inst->environment, inst->name ? inst->name : "",
           (fmi2Status)status, category ? category : "", safe);
    free(safe);
}

/* The folder of a file URI (RFC 8089): "file:///a%20b/", "file:/a/",
 * "file://localhost/a/" give "/a b" etc.; NULL for anything else. */
static char* folder_of_uri(const char* uri)
{
    if (!uri || strncmp(uri, "file:", 5) != 0) return NULL;
    const char* p = uri + 5;
    if (strncmp(p, "///", 3) == 0) p += 2;
    else if (strncmp(p, "//localhost/", 12) == 0) p += 11;
    else if (strncmp(p, "//", 2) == 0) return NULL;   /* another host */
    char* out = (char*)malloc(strlen(p) + 1);
    if (!out) return NULL;
    char* o = out;
    for (; *p; p++) {
        if (*p == '%') {
            int hi, lo;
            if (sscanf(p + 1, "%1x%1x", &hi, &lo) != 2) {
                free(out);
                return NULL;
            }
            *o++ = (char)(hi * 16 + lo);
            p += 2;
        } else {
            *o++ = *p;
        }
    }
    *o = '\0';
    while (o > out + 1 && o[-1] == '/') *--o = '\0';
    return out;
}

FMI2_Export const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char* fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType,
                                          fmi2String fmuGUID, fmi2String fmuResourceLocation,
                                          const fmi2CallbackFunctions* functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance* inst = new_instance(instanceName, emit2,
                                  functions ? functions->componentEnvironment : NULL,
                                  functions ? (void (*)(void))functions->logger : NULL,
                                  loggingOn != fmi2False);
    if (!inst) return NULL;
    if (!inst->name || !instanceName || !*instanceName) {
        logf_(inst, ST_ERROR, "fmi2Instantiate: the instance name is empty");
        free_instance(inst);
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        logf_(inst, ST_ERROR, "fmi2Instantiate: this FMU is for co-simulation only");
        free_instance(inst);
        return NULL;
    }
    char* resources = folder_of_uri(fmuResourceLocation);
    if (!resources) {
        logf_(inst, ST_ERROR, "fmi2Instantiate: the resource location %s is not a local "
              "file URI", fmuResourceLocation ? fmuResourceLocation : "(null)");
        free_instance(inst);
        return NULL;
    }
    int made = instantiate_slave(inst, "fmi2Instantiate", resources, fmuGUID,
                                 visible != fmi2False, loggingOn != fmi2False);
    free(resources);
    if (!made) {
        free_instance(inst);
        return NULL;
    }
    return inst;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) { release_instance((Instance*)c); }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn,
                                           size_t nCategories, const fmi2String categories[])
{
    (void)nCategories;
    (void)categories;
    Instance* inst = (Instance*)c;
    if (!inst) return fmi2Error;
    inst->logging_on = loggingOn != fmi2False;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------
 * Initialization, termination
 * ------------------------------------------------------------------------- */
FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                                           fmi2Real tolerance, fmi2Real startTime,
                                           fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Setup s = {toleranceDefined != fmi2False, tolerance, startTime,
               stopTimeDefined != fmi2False, stopTime};
    return (fmi2Status)simple(c, "setup_experiment", setup_args, &s);
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    return (fmi2Status)simple(c, "enter_initialization_mode", NULL, NULL);
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    return (fmi2Status)simple(c, "exit_initialization_mode", NULL, NULL);
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c)
{
    return (fmi2Status)simple(c, "terminate", NULL, NULL);
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component c)
{
    return (fmi2Status)simple(c, "reset", NULL, NULL);
}

/* ---------------------------------------------------------------------------
 * Values
 * ------------------------------------------------------------------------- */
FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) { return (fmi2Status)get_values(c, "fmi2GetReal", REAL, vr, nvr, value); }
FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) { return (fmi2Status)get_values(c, "fmi2GetInteger", INTEGER, vr, nvr, value); }
FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) { return (fmi2Status)get_values(c, "fmi2GetBoolean", BOOLEAN_INT, vr, nvr, value); }
FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) { return (fmi2Status)get_values(c, "fmi2GetString", STRING, vr, nvr, (void*)value); }
FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) { return (fmi2Status)set_values(c, "fmi2SetReal", REAL, vr, nvr, value); }
FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) { return (fmi2Status)set_values(c, "fmi2SetInteger", INTEGER, vr, nvr, value); }
FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) { return (fmi2Status)set_values(c, "fmi2SetBoolean", BOOLEAN_INT, vr, nvr, value); }
FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) { return (fmi2Status)set_values(c, "fmi2SetString", STRING, vr, nvr, value); }

/* ---------------------------------------------------------------------------
 * FMU states (hfdi_fmu_core.h: every state handed out is tracked until freed)
 * ------------------------------------------------------------------------- */
FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* state)
{
    return (fmi2Status)state_get(c, "fmi2GetFMUstate", state);
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state)
{
    return (fmi2Status)state_set(c, "fmi2SetFMUstate", state);
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* state)
{
    return (fmi2Status)state_free(c, "fmi2FreeFMUstate", state);
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t* size)
{
    return (fmi2Status)state_size(c, "fmi2SerializedFMUstateSize", state, size);
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte out[], size_t size)
{
    return (fmi2Status)state_serialize(c, "fmi2SerializeFMUstate", state, out, size);
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte data[], size_t size,
                                               fmi2FMUstate* state)
{
    return (fmi2Status)state_deserialize(c, "fmi2DeSerializeFMUstate", data, size, state);
}

/* ---------------------------------------------------------------------------
 * Stepping and status
 * ------------------------------------------------------------------------- */
FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                                  fmi2Real communicationStepSize,
                                  fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    return (fmi2Status)do_step(c, "fmi2DoStep", currentCommunicationPoint,
                               communicationStepSize, 0, NULL, NULL);
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c)
{
    Instance* inst = (Instance*)c;
    if (inst) logf_(inst, ST_ERROR, "fmi2CancelStep: doStep always returns when done");
    return fmi2Error;
}

/* The FMU's time (the slave's): after a discarded doStep it is where the FMU
 * stayed, and the start time before the first step. */
static int fmu_time(void* c, const char* function, double* value)
{
    INSTANCE_OR_ERROR(c)
    if (!value) return null_argument(inst, function, "the value pointer");
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* t = invoke(inst, "time", NULL, &status);
    if (t) {
        *value = p_PyFloat_AsDouble(t);
        p_Py_DecRef(t);
    }
    return release(inst, gil, function, status);
}

/* The statuses of an asynchronous doStep: there is none, doStep returns when done. */
static fmi2Status no_status(fmi2Component c, const char* function)
{
    Instance* inst = (Instance*)c;
    if (!inst) return fmi2Error;
    logf_(inst, ST_DISCARD, "%s: this status is not provided (doStep returns when done)",
          function);
    return fmi2Discard;
}

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* value)
{
    (void)s;
    (void)value;
    return no_status(c, "fmi2GetStatus");
}

FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* value)
{
    Instance* inst = (Instance*)c;
    if (!inst || !api_ready || !inst->adapter) return fmi2Error;
    if (!value) return (fmi2Status)null_argument(inst, "fmi2GetRealStatus", "the value pointer");
    if (s != fmi2LastSuccessfulTime) return no_status(c, "fmi2GetRealStatus");
    /* the time of the FMU's last good state, asked of the slave (not kept
       here): after a discarded doStep it is where the FMU stayed, which need
       not be the master's communication point (a doStep from a time the FMU
       is not at), and the start time before the first step */
    return (fmi2Status)fmu_time(c, "fmi2GetRealStatus", value);
}

FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* value)
{
    (void)s;
    (void)value;
    return no_status(c, "fmi2GetIntegerStatus");
}

FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* value)
{
    Instance* inst = (Instance*)c;
    if (!inst || !api_ready || !inst->adapter) return fmi2Error;
    if (s != fmi2Terminated) return no_status(c, "fmi2GetBooleanStatus");
    if (!value) return (fmi2Status)null_argument(inst, "fmi2GetBooleanStatus", "the value pointer");
    *value = fmi2False;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* value)
{
    (void)s;
    (void)value;
    return no_status(c, "fmi2GetStringStatus");
}

/* Not provided (the model description says so): a refusal, not a crash. */
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference z[], size_t nz,
                                                    const fmi2Real du[], fmi2Real dz[])
{
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    return (fmi2Status)not_provided(c, "fmi2GetDirectionalDerivative", NULL);
}

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    return (fmi2Status)not_provided(c, "fmi2SetRealInputDerivatives", NULL);
}

FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                    const fmi2Integer order[], fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    return (fmi2Status)not_provided(c, "fmi2GetRealOutputDerivatives", NULL);
}
