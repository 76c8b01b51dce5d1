/* A host that is not Python, for the tests of the FMU's native layer.
 *
 * usage: fmi2_host LIBRARY RESOURCE_URI GUID STEPS [s<vr>=<text>]... [<vr>]...
 *
 * Loads the FMU's binary, instantiates it, sets the String values given as
 * s<vr>=<text> in initialization mode, takes STEPS steps of 0.01 and prints
 * the Real values of the references given as numbers ("value <vr> <x>").
 * The logger formats each message as FMI 2.0 defines it, a printf format
 * with the arguments that follow (none here), as a C master would.
 * Exit status: 0 done, 1 fmi2Instantiate gave NULL, 4 initialization refused,
 * 5 a step not taken, 6 a value not read, 2 and 3 usage and loading.
 */
#include <dlfcn.h>
#include <locale.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    char text[8192];
    va_list ap;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message, ap);
    va_end(ap);
    printf("log %s %d %s: %s\n", name, (int)status, category, text);
    fflush(stdout);
}

#define LOAD(f)                                                                    \
    f##TYPE* f = (f##TYPE*)dlsym(lib, #f);                                         \
    if (!f) {                                                                      \
        printf("missing %s\n", #f);                                                \
        return 3;                                                                  \
    }

int main(int argc, char** argv)
{
    if (argc < 5) {
        printf("usage: fmi2_host LIBRARY RESOURCE_URI GUID STEPS [s<vr>=<text>]... "
               "[b<vr>=<0|1>]... [r<vr>=<real>]... [<vr>]...\n");
        return 2;
    }
    void* lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("dlopen: %s\n", dlerror());
        return 3;
    }
    LOAD(fmi2Instantiate)
    LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode)
    LOAD(fmi2SetString)
    LOAD(fmi2SetBoolean)
    LOAD(fmi2SetReal)
    LOAD(fmi2DoStep)
    LOAD(fmi2GetReal)
    LOAD(fmi2Terminate)
    LOAD(fmi2FreeInstance)
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, argv[3], argv[2], &callbacks,
                                      fmi2False, fmi2True);
    if (!c) {
        printf("instantiate: NULL\n");
        return 1;
    }
    int status = 0;
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK
        || fmi2EnterInitializationMode(c) != fmi2OK)
        status = 4;
    for (int i = 5; !status && i < argc; i++) {
        if (argv[i][0] != 's' && argv[i][0] != 'b') continue;
        char* equals = strchr(argv[i], '=');
        if (!equals) return 2;
        fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i] + 1);
        if (argv[i][0] == 'b') {
            fmi2Boolean value = atoi(equals + 1) != 0;
            if (fmi2SetBoolean(c, &vr, 1, &value) != fmi2OK) status = 4;
            continue;
        }
        fmi2String value = equals + 1;
        if (fmi2SetString(c, &vr, 1, &value) != fmi2OK) status = 4;
    }
    if (!status && fmi2ExitInitializationMode(c) != fmi2OK) status = 4;
    double t = 0.0, h = 0.01;
    int steps = atoi(argv[4]);
    for (int k = 0; !status && k < steps; k++, t += h) {
        /* r<vr>=<real>: an input set before the step at the middle of the run */
        for (int i = 5; k == steps / 2 && !status && i < argc; i++) {
            if (argv[i][0] != 'r') continue;
            char* equals = strchr(argv[i], '=');
            if (!equals) return 2;
            fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i] + 1);
            double value = atof(equals + 1);
            if (fmi2SetReal(c, &vr, 1, &value) != fmi2OK) status = 5;
        }
        if (!status && fmi2DoStep(c, t, h, fmi2True) != fmi2OK) status = 5;
    }
    for (int i = 5; !status && i < argc; i++) {
        if (argv[i][0] == 's' || argv[i][0] == 'b' || argv[i][0] == 'r') continue;
        fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i]);
        double value;
        if (fmi2GetReal(c, &vr, 1, &value) != fmi2OK) status = 6;
        else printf("value %u %.17g\n", vr, value);
    }
    if (!status) fmi2Terminate(c);
    fmi2FreeInstance(c);
    /* a C program runs in the "C" locale until it sets another: the FMU must not */
    printf("locale %s\n", setlocale(LC_ALL, NULL));
    return status;
}
