/* A host that is not Python: loads an FMU's binary, runs a few steps. */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    char text[4096];
    va_list ap;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message, ap);   /* the message is a printf format */
    va_end(ap);
    printf("log %s %d %s: %s\n", name, (int)status, category, text);
}

#define LOAD(f) f##TYPE* f = (f##TYPE*)dlsym(lib, #f); if (!f) { printf("missing %s\n", #f); return 3; }

int main(int argc, char** argv)
{
    if (argc < 5) { printf("usage: host LIBRARY RESOURCE_URI GUID STEPS [VR...]\n"); return 2; }
    void* lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { printf("dlopen: %s\n", dlerror()); return 3; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2DoStep) LOAD(fmi2GetReal) LOAD(fmi2FreeInstance)
    LOAD(fmi2Terminate)
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, argv[3], argv[2], &cb, fmi2False, fmi2True);
    if (!c) { printf("instantiate: NULL\n"); return 1; }
    int steps = atoi(argv[4]);
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK) return 4;
    if (fmi2EnterInitializationMode(c) != fmi2OK) return 4;
    if (fmi2ExitInitializationMode(c) != fmi2OK) return 4;
    double t = 0.0, h = 0.01;
    for (int k = 0; k < steps; k++, t += h)
        if (fmi2DoStep(c, t, h, fmi2True) != fmi2OK) { printf("doStep failed at %g\n", t); return 5; }
    for (int i = 5; i < argc; i++) {
        fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i]);
        double value;
        if (fmi2GetReal(c, &vr, 1, &value) != fmi2OK) return 6;
        printf("value %u %.17g\n", vr, value);
    }
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    return 0;
}
