/* A host that is not Python and instantiates an FMU from several threads at
 * once, for the tests of the FMU's native layer.
 *
 * usage: fmi2_threads LIBRARY RESOURCE_URI GUID THREADS STEPS [<vr>]...
 *
 * Loads the FMU's binary, starts THREADS threads that wait for each other
 * and then all call fmi2Instantiate at the same moment (the first
 * instantiation of the process: the native layer starts Python then); each
 * thread then initializes its instance, takes STEPS steps of 0.01 and reads
 * the Real values of the references given. Prints "value <thread> <vr> <x>"
 * for every thread and reference, after all threads are done.
 * Exit status: 0 every thread done, 1 some instance failed (NULL, a refused
 * call), 2 and 3 usage and loading.
 */
#include <dlfcn.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define MAX_THREADS 64
#define MAX_VRS 16

static fmi2InstantiateTYPE* instantiate;
static fmi2SetupExperimentTYPE* setup;
static fmi2EnterInitializationModeTYPE* enter;
static fmi2ExitInitializationModeTYPE* leave;
static fmi2DoStepTYPE* step;
static fmi2GetRealTYPE* get_real;
static fmi2TerminateTYPE* terminate;
static fmi2FreeInstanceTYPE* free_instance;

static const char *uri, *guid;
static int steps, n_vrs;
static fmi2ValueReference vrs[MAX_VRS];
static pthread_barrier_t start;

typedef struct {
    int index, failed;
    double values[MAX_VRS];
} Work;

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

static void* run(void* data)
{
    Work* work = (Work*)data;
    char name[32];
    snprintf(name, sizeof name, "thread%d", work->index);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    pthread_barrier_wait(&start);
    fmi2Component c = instantiate(name, fmi2CoSimulation, guid, uri, &callbacks, fmi2False,
                                  fmi2False);
    if (!c) {
        work->failed = 1;
        return NULL;
    }
    if (setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK || enter(c) != fmi2OK
        || leave(c) != fmi2OK)
        work->failed = 2;
    double t = 0.0;
    for (int k = 0; !work->failed && k < steps; k++, t += 0.01)
        if (step(c, t, 0.01, fmi2True) != fmi2OK) work->failed = 3;
    if (!work->failed && n_vrs && get_real(c, vrs, (size_t)n_vrs, work->values) != fmi2OK)
        work->failed = 4;
    if (!work->failed) terminate(c);
    free_instance(c);
    return NULL;
}

int main(int argc, char** argv)
{
    if (argc < 6) {
        printf("usage: fmi2_threads LIBRARY RESOURCE_URI GUID THREADS STEPS [<vr>]...\n");
        return 2;
    }
    void* lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("dlopen: %s\n", dlerror());
        return 3;
    }
    struct { void** target; const char* name; } symbols[] = {
        {(void**)&instantiate, "fmi2Instantiate"},
        {(void**)&setup, "fmi2SetupExperiment"},
        {(void**)&enter, "fmi2EnterInitializationMode"},
        {(void**)&leave, "fmi2ExitInitializationMode"},
        {(void**)&step, "fmi2DoStep"},
        {(void**)&get_real, "fmi2GetReal"},
        {(void**)&terminate, "fmi2Terminate"},
        {(void**)&free_instance, "fmi2FreeInstance"},
    };
    for (size_t i = 0; i < sizeof symbols / sizeof symbols[0]; i++) {
        *symbols[i].target = dlsym(lib, symbols[i].name);
        if (!*symbols[i].target) {
            printf("missing %s\n", symbols[i].name);
            return 3;
        }
    }
    uri = argv[2];
    guid = argv[3];
    int threads = atoi(argv[4]);
    steps = atoi(argv[5]);
    n_vrs = argc - 6;
    if (threads < 1 || threads > MAX_THREADS || n_vrs > MAX_VRS) return 2;
    for (int i = 0; i < n_vrs; i++) vrs[i] = (fmi2ValueReference)atoi(argv[6 + i]);
    pthread_barrier_init(&start, NULL, (unsigned)threads);
    pthread_t ids[MAX_THREADS];
    Work work[MAX_THREADS];
    memset(work, 0, sizeof work);
    for (int k = 0; k < threads; k++) {
        work[k].index = k;
        if (pthread_create(&ids[k], NULL, run, &work[k]) != 0) return 3;
    }
    int failed = 0;
    for (int k = 0; k < threads; k++) pthread_join(ids[k], NULL);
    for (int k = 0; k < threads; k++) {
        if (work[k].failed) {
            printf("failed %d at %d\n", k, work[k].failed);
            failed = 1;
            continue;
        }
        for (int i = 0; i < n_vrs; i++)
            printf("value %d %u %.17g\n", k, vrs[i], work[k].values[i]);
    }
    return failed;
}
