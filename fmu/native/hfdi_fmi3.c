/*
 * The native layer of hfdi's FMI 3.0 co-simulation FMUs.
 *
 * Every function of fmi3Functions.h, written against the FMI 3.0 headers,
 * on the same core as the FMI 2.0 layer (hfdi_fmu_core.h: the CPython C API
 * resolved at run time, the slave of fmu/slave.py behind fmu/entry.py's
 * adapter). The FMU is for co-simulation only, without event mode: a zero of
 * a model's event function inside a communication step is handled inside
 * the step (the model's reset applied there); with earlyReturnAllowed,
 * fmi3DoStep returns at it (earlyReturn = fmi3True, lastSuccessfulTime its
 * time, the state after the reset), and the master goes on from there.
 *
 * Statuses:
 *   fmi3Error    a refused call (bad argument, value reference, state, an
 *                exception of the slave; a function that does not apply to
 *                this FMU: model exchange, scheduled execution, event mode,
 *                clocks, types it has no variables of, derivatives), with one
 *                log message; the instance is as before the call;
 *   fmi3Discard  a step not taken: the FMU is back at its start
 *                (lastSuccessfulTime says where), the log says why;
 *   fmi3Fatal    never.
 * An instantiation that cannot be made returns NULL after one log message.
 * Messages reach the logger as they are (FMI 3.0's message is no format).
 */
#include "hfdi_fmu_core.h"

#include "fmi3Functions.h"

static void emit3(const Instance* inst, int status, const char* category, const char* text)
{
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)inst->logger;
    if (logger)
        logger((fmi3InstanceEnvironment)inst->environment, (fmi3Status)status,
               category ? category : "", text);
}

/* A log message before an instance exists (fmi3Instantiate* refusing). */
static void refuse(const char* name, fmi3InstanceEnvironment environment,
                   fmi3LogMessageCallback logger, const char* text)
{
    Instance* inst = new_instance(name ? name : "", emit3, environment,
                                  (void (*)(void))logger, 1);
    if (inst) {
        logf_(inst, ST_ERROR, "%s", text);
        free_instance(inst);
    }
}

FMI3_Export const char* fmi3GetVersion(void) { return fmi3Version; }

FMI3_Export fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn,
                                           size_t nCategories, const fmi3String categories[])
{
    (void)nCategories;
    (void)categories;
    Instance* inst = (Instance*)instance;
    if (!inst) return fmi3Error;
    inst->logging_on = loggingOn;
    return fmi3OK;
}

FMI3_Export fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    const char* function = "fmi3InstantiateCoSimulation";
    Instance* inst = new_instance(instanceName, emit3, instanceEnvironment,
                                  (void (*)(void))logMessage, loggingOn);
    if (!inst) return NULL;
    inst->early_return = earlyReturnAllowed;
    if (!inst->name || !instanceName || !*instanceName) {
        logf_(inst, ST_ERROR, "%s: the instance name is empty", function);
        free_instance(inst);
        return NULL;
    }
    if (!resourcePath || !*resourcePath) {
        logf_(inst, ST_ERROR, "%s: resourcePath is %s; this FMU needs its resources folder",
              function, resourcePath ? "empty" : "NULL");
        free_instance(inst);
        return NULL;
    }
    if (eventModeUsed)
        logf_(inst, ST_WARNING, "%s: eventModeUsed: this FMU has no event mode "
              "(hasEventMode = false); zeros of its event functions are handled inside "
              "fmi3DoStep, which returns early at them when earlyReturnAllowed", function);
    if (nRequiredIntermediateVariables)
        logf_(inst, ST_WARNING, "%s: %zu required intermediate variables: this FMU provides "
              "no intermediate update; they are not updated", function,
              nRequiredIntermediateVariables);
    /* resourcePath: an absolute path ending in a separator */
    char* resources = copy_text(resourcePath);
    size_t n = resources ? strlen(resources) : 0;
    while (n > 1 && resources[n - 1] == '/') resources[--n] = '\0';
    int made = resources && instantiate_slave(inst, function, resources, instantiationToken,
                                              visible, loggingOn);
    free(resources);
    if (!made) {
        free_instance(inst);
        return NULL;
    }
    return inst;
}

FMI3_Export fmi3Instance fmi3InstantiateModelExchange(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage)
{
    (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    refuse(instanceName, instanceEnvironment, logMessage,
           "fmi3InstantiateModelExchange: this FMU is for co-simulation only");
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    refuse(instanceName, instanceEnvironment, logMessage,
           "fmi3InstantiateScheduledExecution: this FMU is for co-simulation only");
    return NULL;
}

FMI3_Export void fmi3FreeInstance(fmi3Instance instance) { release_instance((Instance*)instance); }

/* ---------------------------------------------------------------------------
 * Initialization, termination
 * ------------------------------------------------------------------------- */
FMI3_Export fmi3Status fmi3EnterInitializationMode(fmi3Instance instance,
                                                   fmi3Boolean toleranceDefined,
                                                   fmi3Float64 tolerance, fmi3Float64 startTime,
                                                   fmi3Boolean stopTimeDefined,
                                                   fmi3Float64 stopTime)
{
    Setup s = {toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime};
    return (fmi3Status)simple(instance, "enter_initialization", setup_args, &s);
}

FMI3_Export fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    return (fmi3Status)simple(instance, "exit_initialization_mode", NULL, NULL);
}

FMI3_Export fmi3Status fmi3Terminate(fmi3Instance instance)
{
    return (fmi3Status)simple(instance, "terminate", NULL, NULL);
}

FMI3_Export fmi3Status fmi3Reset(fmi3Instance instance)
{
    return (fmi3Status)simple(instance, "reset", NULL, NULL);
}

#define NO_EVENT_MODE "this FMU has no event mode (hasEventMode = false)"

FMI3_Export fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    return (fmi3Status)not_provided(instance, "fmi3EnterEventMode", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    return (fmi3Status)not_provided(instance, "fmi3EnterStepMode", NO_EVENT_MODE
                                    "; it is in step mode from fmi3ExitInitializationMode on");
}

FMI3_Export fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    return (fmi3Status)not_provided(instance, "fmi3EvaluateDiscreteStates", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance,
                                                fmi3Boolean* discreteStatesNeedUpdate,
                                                fmi3Boolean* terminateSimulation,
                                                fmi3Boolean* nominalsOfContinuousStatesChanged,
                                                fmi3Boolean* valuesOfContinuousStatesChanged,
                                                fmi3Boolean* nextEventTimeDefined,
                                                fmi3Float64* nextEventTime)
{
    (void)discreteStatesNeedUpdate; (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged; (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined; (void)nextEventTime;
    return (fmi3Status)not_provided(instance, "fmi3UpdateDiscreteStates", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance)
{
    return (fmi3Status)not_provided(instance, "fmi3EnterConfigurationMode",
                                    "this FMU has no structural parameters");
}

FMI3_Export fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance)
{
    return (fmi3Status)not_provided(instance, "fmi3ExitConfigurationMode",
                                    "this FMU has no structural parameters");
}

/* ---------------------------------------------------------------------------
 * Values: every variable is a scalar (nValues must equal nValueReferences);
 * the FMU has Float64, Int32, Boolean and String variables only.
 * ------------------------------------------------------------------------- */
static int scalars(fmi3Instance instance, const char* function, size_t nvr, size_t n_values)
{
    if (nvr == n_values) return 1;
    Instance* inst = (Instance*)instance;
    if (inst) logf_(inst, ST_ERROR, "%s: nValues = %zu but nValueReferences = %zu: every "
                    "variable of this FMU is a scalar", function, n_values, nvr);
    return 0;
}

static fmi3Status get3(fmi3Instance instance, const char* function, Kind kind,
                       const fmi3ValueReference vr[], size_t nvr, void* values, size_t n_values)
{
    if (!scalars(instance, function, nvr, n_values)) return fmi3Error;
    return (fmi3Status)get_values(instance, function, kind, vr, nvr, values);
}

static fmi3Status set3(fmi3Instance instance, const char* function, Kind kind,
                       const fmi3ValueReference vr[], size_t nvr, const void* values,
                       size_t n_values)
{
    if (!scalars(instance, function, nvr, n_values)) return fmi3Error;
    return (fmi3Status)set_values(instance, function, kind, vr, nvr, values);
}

/* A get or set of a type this FMU has no variables of: every reference is wrong. */
static fmi3Status no_variables(fmi3Instance instance, const char* function, const char* type,
                               const fmi3ValueReference vr[], size_t nvr)
{
    Instance* inst = (Instance*)instance;
    if (!inst) return fmi3Error;
    if (nvr == 0) return fmi3OK;
    logf_(inst, ST_ERROR, "%s: value reference %u is not a %s variable: this FMU has none",
          function, vr ? (unsigned)vr[0] : 0u, type);
    return fmi3Error;
}

FMI3_Export fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[], size_t nValues) { return get3(c, "fmi3GetFloat64", REAL, vr, nvr, values, nValues); }
FMI3_Export fmi3Status fmi3GetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[], size_t nValues) { return get3(c, "fmi3GetInt32", INTEGER, vr, nvr, values, nValues); }
FMI3_Export fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Boolean values[], size_t nValues) { return get3(c, "fmi3GetBoolean", BOOLEAN_BYTE, vr, nvr, values, nValues); }
FMI3_Export fmi3Status fmi3GetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3String values[], size_t nValues) { return get3(c, "fmi3GetString", STRING, vr, nvr, (void*)values, nValues); }
FMI3_Export fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[], size_t nValues) { return set3(c, "fmi3SetFloat64", REAL, vr, nvr, values, nValues); }
FMI3_Export fmi3Status fmi3SetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[], size_t nValues) { return set3(c, "fmi3SetInt32", INTEGER, vr, nvr, values, nValues); }
FMI3_Export fmi3Status fmi3SetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Boolean values[], size_t nValues) { return set3(c, "fmi3SetBoolean", BOOLEAN_BYTE, vr, nvr, values, nValues); }
FMI3_Export fmi3Status fmi3SetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3String values[], size_t nValues) { return set3(c, "fmi3SetString", STRING, vr, nvr, (const void*)values, nValues); }

#define NO_VARIABLES(NAME, TYPE, ELEMENT, CONST)                                    \
    FMI3_Export fmi3Status NAME(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
                                CONST ELEMENT values[], size_t nValues)             \
    {                                                                               \
        (void)values; (void)nValues;                                                \
        return no_variables(c, #NAME, TYPE, vr, nvr);                               \
    }
NO_VARIABLES(fmi3GetFloat32, "Float32", fmi3Float32, )
NO_VARIABLES(fmi3GetInt8, "Int8", fmi3Int8, )
NO_VARIABLES(fmi3GetUInt8, "UInt8", fmi3UInt8, )
NO_VARIABLES(fmi3GetInt16, "Int16", fmi3Int16, )
NO_VARIABLES(fmi3GetUInt16, "UInt16", fmi3UInt16, )
NO_VARIABLES(fmi3GetUInt32, "UInt32", fmi3UInt32, )
NO_VARIABLES(fmi3GetInt64, "Int64", fmi3Int64, )
NO_VARIABLES(fmi3GetUInt64, "UInt64", fmi3UInt64, )
NO_VARIABLES(fmi3SetFloat32, "Float32", fmi3Float32, const)
NO_VARIABLES(fmi3SetInt8, "Int8", fmi3Int8, const)
NO_VARIABLES(fmi3SetUInt8, "UInt8", fmi3UInt8, const)
NO_VARIABLES(fmi3SetInt16, "Int16", fmi3Int16, const)
NO_VARIABLES(fmi3SetUInt16, "UInt16", fmi3UInt16, const)
NO_VARIABLES(fmi3SetUInt32, "UInt32", fmi3UInt32, const)
NO_VARIABLES(fmi3SetInt64, "Int64", fmi3Int64, const)
NO_VARIABLES(fmi3SetUInt64, "UInt64", fmi3UInt64, const)

FMI3_Export fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                     size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    (void)valueSizes; (void)values; (void)nValues;
    return no_variables(c, "fmi3GetBinary", "Binary", vr, nvr);
}

FMI3_Export fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                     const size_t valueSizes[], const fmi3Binary values[],
                                     size_t nValues)
{
    (void)valueSizes; (void)values; (void)nValues;
    return no_variables(c, "fmi3SetBinary", "Binary", vr, nvr);
}

FMI3_Export fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                    fmi3Clock values[])
{
    (void)values;
    return no_variables(c, "fmi3GetClock", "Clock", vr, nvr);
}

FMI3_Export fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Clock values[])
{
    (void)values;
    return no_variables(c, "fmi3SetClock", "Clock", vr, nvr);
}

#define NO_CLOCKS "this FMU has no clocks"

FMI3_Export fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[],
                                              size_t nvr, fmi3Float64 intervals[],
                                              fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    return (fmi3Status)not_provided(c, "fmi3GetIntervalDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[],
                                               size_t nvr, fmi3UInt64 counters[],
                                               fmi3UInt64 resolutions[],
                                               fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    return (fmi3Status)not_provided(c, "fmi3GetIntervalFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[],
                                           size_t nvr, fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return (fmi3Status)not_provided(c, "fmi3GetShiftDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[],
                                            size_t nvr, fmi3UInt64 counters[],
                                            fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return (fmi3Status)not_provided(c, "fmi3GetShiftFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[],
                                              size_t nvr, const fmi3Float64 intervals[])
{
    (void)vr; (void)nvr; (void)intervals;
    return (fmi3Status)not_provided(c, "fmi3SetIntervalDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[],
                                               size_t nvr, const fmi3UInt64 counters[],
                                               const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return (fmi3Status)not_provided(c, "fmi3SetIntervalFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[],
                                           size_t nvr, const fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return (fmi3Status)not_provided(c, "fmi3SetShiftDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[],
                                            size_t nvr, const fmi3UInt64 counters[],
                                            const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return (fmi3Status)not_provided(c, "fmi3SetShiftFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clock,
                                                  fmi3Float64 activationTime)
{
    (void)clock; (void)activationTime;
    return (fmi3Status)not_provided(c, "fmi3ActivateModelPartition",
                                    "this FMU is for co-simulation only");
}

/* ---------------------------------------------------------------------------
 * Dependencies and derivatives: not provided (the model description says so)
 * ------------------------------------------------------------------------- */
FMI3_Export fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c,
                                                           fmi3ValueReference valueReference,
                                                           size_t* nDependencies)
{
    (void)valueReference; (void)nDependencies;
    return (fmi3Status)not_provided(c, "fmi3GetNumberOfVariableDependencies",
                                    "no output depends on an input directly "
                                    "(<ModelStructure>)");
}

FMI3_Export fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference dependent,
                                                   size_t elementIndicesOfDependent[],
                                                   fmi3ValueReference independents[],
                                                   size_t elementIndicesOfIndependents[],
                                                   fmi3DependencyKind dependencyKinds[],
                                                   size_t nDependencies)
{
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return (fmi3Status)not_provided(c, "fmi3GetVariableDependencies",
                                    "no output depends on an input directly "
                                    "(<ModelStructure>)");
}

FMI3_Export fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[],
                                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                                    fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return (fmi3Status)not_provided(c, "fmi3GetDirectionalDerivative", NULL);
}

FMI3_Export fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[],
                                                size_t nUnknowns, const fmi3ValueReference knowns[],
                                                size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                                fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return (fmi3Status)not_provided(c, "fmi3GetAdjointDerivative", NULL);
}

FMI3_Export fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[],
                                                size_t nvr, const fmi3Int32 orders[],
                                                fmi3Float64 values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)orders; (void)values; (void)nValues;
    return (fmi3Status)not_provided(c, "fmi3GetOutputDerivatives", NULL);
}

/* ---------------------------------------------------------------------------
 * FMU states (hfdi_fmu_core.h: every state handed out is tracked until freed)
 * ------------------------------------------------------------------------- */
FMI3_Export fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState* state)
{
    return (fmi3Status)state_get(c, "fmi3GetFMUState", state);
}

FMI3_Export fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState state)
{
    return (fmi3Status)state_set(c, "fmi3SetFMUState", state);
}

FMI3_Export fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState* state)
{
    return (fmi3Status)state_free(c, "fmi3FreeFMUState", state);
}

FMI3_Export fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState state, size_t* size)
{
    return (fmi3Status)state_size(c, "fmi3SerializedFMUStateSize", state, size);
}

FMI3_Export fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState state,
                                             fmi3Byte serializedState[], size_t size)
{
    return (fmi3Status)state_serialize(c, "fmi3SerializeFMUState", state,
                                       (char*)serializedState, size);
}

FMI3_Export fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte serializedState[],
                                               size_t size, fmi3FMUState* state)
{
    return (fmi3Status)state_deserialize(c, "fmi3DeserializeFMUState",
                                         (const char*)serializedState, size, state);
}

/* ---------------------------------------------------------------------------
 * Stepping
 * ------------------------------------------------------------------------- */
FMI3_Export fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint,
                                  fmi3Float64 communicationStepSize,
                                  fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                  fmi3Boolean* eventHandlingNeeded,
                                  fmi3Boolean* terminateSimulation, fmi3Boolean* earlyReturn,
                                  fmi3Float64* lastSuccessfulTime)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance* inst = (Instance*)c;
    if (!inst || !api_ready || !inst->adapter) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return (fmi3Status)null_argument(inst, "fmi3DoStep", "an output argument "
                                         "(eventHandlingNeeded, terminateSimulation, "
                                         "earlyReturn or lastSuccessfulTime)");
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = currentCommunicationPoint;
    bool early = false;
    int status = do_step(c, "fmi3DoStep", currentCommunicationPoint, communicationStepSize,
                         inst->early_return, &early, lastSuccessfulTime);
    *earlyReturn = status == ST_OK && early;
    return (fmi3Status)status;
}

/* ---------------------------------------------------------------------------
 * Model exchange: not this FMU's
 * ------------------------------------------------------------------------- */
#define ME_ONLY "this FMU is for co-simulation only"

FMI3_Export fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c)
{
    return (fmi3Status)not_provided(c, "fmi3EnterContinuousTimeMode", ME_ONLY);
}

FMI3_Export fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c,
                                                   fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                                   fmi3Boolean* enterEventMode,
                                                   fmi3Boolean* terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return (fmi3Status)not_provided(c, "fmi3CompletedIntegratorStep", ME_ONLY);
}

FMI3_Export fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time)
{
    (void)time;
    return (fmi3Status)not_provided(c, "fmi3SetTime", ME_ONLY);
}

FMI3_Export fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 x[], size_t nx)
{
    (void)x; (void)nx;
    return (fmi3Status)not_provided(c, "fmi3SetContinuousStates", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 dx[], size_t nx)
{
    (void)dx; (void)nx;
    return (fmi3Status)not_provided(c, "fmi3GetContinuousStateDerivatives", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 z[], size_t nz)
{
    (void)z; (void)nz;
    return (fmi3Status)not_provided(c, "fmi3GetEventIndicators", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t nx)
{
    (void)x; (void)nx;
    return (fmi3Status)not_provided(c, "fmi3GetContinuousStates", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 nominals[],
                                                         size_t nx)
{
    (void)nominals; (void)nx;
    return (fmi3Status)not_provided(c, "fmi3GetNominalsOfContinuousStates", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t* n)
{
    (void)n;
    return (fmi3Status)not_provided(c, "fmi3GetNumberOfEventIndicators", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t* n)
{
    (void)n;
    return (fmi3Status)not_provided(c, "fmi3GetNumberOfContinuousStates", ME_ONLY);
}
