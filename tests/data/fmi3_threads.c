/* A host that is not Python and runs an FMI 3.0 FMU from several threads at
 * once, for the tests of the FMU's native layer.
 *
 * usage: fmi3_threads LIBRARY RESOURCE_PATH TOKEN THREADS T_END H [<vr>]...
 *
 * Loads the FMU's binary; THREADS threads wait for each other and then all
 * call fmi3InstantiateCoSimulation (earlyReturnAllowed) at the same moment
 * (the first instantiation of the process: the native layer starts Python
 * then); each initializes its instance and steps to T_END by H, going on
 * from lastSuccessfulTime after an early return, and reads the Float64
 * values of the references given. Prints "early <thread> <t>" for every
 * early return and "value <thread> <vr> <x>" for every reference, after all
 * threads are done. Exit status: 0 every thread done, 1 some instance failed
 * (NULL, a refused call), 2 and 3 usage and loading.
 */
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"

#define MAX_THREADS 64
#define MAX_VRS 16
#define MAX_EARLY 256

static fmi3InstantiateCoSimulationTYPE* instantiate;
static fmi3EnterInitializationModeTYPE* enter;
static fmi3ExitInitializationModeTYPE* leave;
static fmi3DoStepTYPE* step;
static fmi3GetFloat64TYPE* get_float64;
static fmi3TerminateTYPE* terminate;
static fmi3FreeInstanceTYPE* free_instance;

static const char *resources, *token;
static double t_end, h;
static int n_vrs;
static fmi3ValueReference vrs[MAX_VRS];
static pthread_barrier_t start;

typedef struct {
    int index, failed, n_early;
    double values[MAX_VRS], early[MAX_EARLY];
} Work;

static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                   fmi3String message)
{
    printf("log %d %d %s: %s\n", *(int*)env, (int)status, category, message);
    fflush(stdout);
}

static void* run(void* data)
{
    Work* work = (Work*)data;
    char name[32];
    snprintf(name, sizeof name, "thread%d", work->index);
    pthread_barrier_wait(&start);
    fmi3Instance c = instantiate(name, token, resources, fmi3False, fmi3False, fmi3False,
                                 fmi3True, NULL, 0, &work->index, logger, NULL);
    if (!c) {
        work->failed = 1;
        return NULL;
    }
    if (enter(c, fmi3False, 0.0, 0.0, fmi3True, t_end) != fmi3OK || leave(c) != fmi3OK)
        work->failed = 2;
    double t = 0.0;
    while (!work->failed && t < t_end - 1e-12) {
        double size = t + h > t_end ? t_end - t : h;
        fmi3Boolean handling, stop, early;
        fmi3Float64 last;
        if (step(c, t, size, fmi3True, &handling, &stop, &early, &last) != fmi3OK) {
            work->failed = 3;
            break;
        }
        if (early) {
            if (work->n_early < MAX_EARLY) work->early[work->n_early++] = last;
            t = last;
        } else {
            t += size;
        }
    }
    if (!work->failed && n_vrs
        && get_float64(c, vrs, (size_t)n_vrs, work->values, (size_t)n_vrs) != fmi3OK)
        work->failed = 4;
    if (!work->failed) terminate(c);
    free_instance(c);
    return NULL;
}

int main(int argc, char** argv)
{
    if (argc < 7) {
        printf("usage: fmi3_threads LIBRARY RESOURCE_PATH TOKEN THREADS T_END H [<vr>]...\n");
        return 2;
    }
    void* lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("dlopen: %s\n", dlerror());
        return 3;
    }
    struct { void** target; const char* name; } symbols[] = {
        {(void**)&instantiate, "fmi3InstantiateCoSimulation"},
        {(void**)&enter, "fmi3EnterInitializationMode"},
        {(void**)&leave, "fmi3ExitInitializationMode"},
        {(void**)&step, "fmi3DoStep"},
        {(void**)&get_float64, "fmi3GetFloat64"},
        {(void**)&terminate, "fmi3Terminate"},
        {(void**)&free_instance, "fmi3FreeInstance"},
    };
    for (size_t i = 0; i < sizeof symbols / sizeof symbols[0]; i++) {
        *symbols[i].target = dlsym(lib, symbols[i].name);
        if (!*symbols[i].target) {
            printf("missing %s\n", symbols[i].name);
            return 3;
        }
    }
    resources = argv[2];
    token = argv[3];
    int threads = atoi(argv[4]);
    t_end = atof(argv[5]);
    h = atof(argv[6]);
    n_vrs = argc - 7;
    if (threads < 1 || threads > MAX_THREADS || n_vrs > MAX_VRS || !(h > 0)) return 2;
    for (int i = 0; i < n_vrs; i++) vrs[i] = (fmi3ValueReference)atoi(argv[7 + i]);
    pthread_barrier_init(&start, NULL, (unsigned)threads);
    pthread_t ids[MAX_THREADS];
    static Work work[MAX_THREADS];
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
        for (int i = 0; i < work[k].n_early; i++) printf("early %d %.17g\n", k, work[k].early[i]);
        for (int i = 0; i < n_vrs; i++)
            printf("value %d %u %.17g\n", k, vrs[i], work[k].values[i]);
    }
    return failed;
}
