/*
 * What the native layers of hfdi's FMI 2.0 and FMI 3.0 co-simulation FMUs
 * share (hfdi_fmi2.c, hfdi_fmi3.c include it; each is one library): the
 * CPython C API resolved at run time, the interpreter started once, the
 * entry module loaded, the instance and its log, calls of the slave's
 * adapter, the native path's gate, values and FMU states. Nothing here
 * depends on an FMI header: statuses are ST_* (the values both versions
 * give fmiXOK ... fmiXFatal), and each layer passes its own function names
 * for the log and its own emit function for the host's logger.
 *
 * Nothing here raises or aborts: every failure becomes a status and one log
 * message, and no Python exception is left pending when a call returns.
 * Sizes given by the master are checked before an array is read or a Python
 * object of that size is made.
 */
#ifndef HFDI_FMU_CORE_H
#define HFDI_FMU_CORE_H
#define _GNU_SOURCE
#include <dlfcn.h>
#include <locale.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stdbool.h>
#include <time.h>

enum { ST_OK = 0, ST_WARNING = 1, ST_DISCARD = 2, ST_ERROR = 3, ST_FATAL = 4, ST_PENDING = 5 };
typedef unsigned int ValueReference;    /* fmi2ValueReference, fmi3ValueReference */


/* ---------------------------------------------------------------------------
 * The CPython C API, by name. Only functions (no macros, no struct layouts)
 * so that no header of a particular Python version is needed.
 * ------------------------------------------------------------------------- */
typedef void PyObject;
typedef long Py_ssize_t_;
typedef int PyGILState;

#define API(ret, name, args) static ret(*p_##name) args;
#define API_LIST                                                                   \
    API(int, Py_IsInitialized, (void))                                             \
    API(void, Py_InitializeEx, (int))                                              \
    API(void, Py_SetPythonHome, (const wchar_t*))                                  \
    API(wchar_t*, Py_DecodeLocale, (const char*, size_t*))                         \
    API(void*, PyEval_SaveThread, (void))                                          \
    API(PyGILState, PyGILState_Ensure, (void))                                     \
    API(void, PyGILState_Release, (PyGILState))                                    \
    API(void, Py_IncRef, (PyObject*))                                              \
    API(void, Py_DecRef, (PyObject*))                                              \
    API(PyObject*, PyImport_ImportModule, (const char*))                           \
    API(PyObject*, PyObject_GetAttrString, (PyObject*, const char*))               \
    API(PyObject*, PyObject_CallObject, (PyObject*, PyObject*))                    \
    API(PyObject*, PyObject_Str, (PyObject*))                                      \
    API(int, PyObject_IsTrue, (PyObject*))                                         \
    API(PyObject*, PyTuple_New, (Py_ssize_t_))                                     \
    API(int, PyTuple_SetItem, (PyObject*, Py_ssize_t_, PyObject*))                 \
    API(PyObject*, PyTuple_GetItem, (PyObject*, Py_ssize_t_))                      \
    API(PyObject*, PyList_New, (Py_ssize_t_))                                      \
    API(int, PyList_SetItem, (PyObject*, Py_ssize_t_, PyObject*))                  \
    API(PyObject*, PyList_GetItem, (PyObject*, Py_ssize_t_))                       \
    API(Py_ssize_t_, PyList_Size, (PyObject*))                                     \
    API(PyObject*, PyUnicode_DecodeFSDefault, (const char*))                       \
    API(PyObject*, PyUnicode_DecodeUTF8, (const char*, Py_ssize_t_, const char*))  \
    API(const char*, PyUnicode_AsUTF8AndSize, (PyObject*, Py_ssize_t_*))           \
    API(PyObject*, PyLong_FromLong, (long))                                        \
    API(PyObject*, PyLong_FromUnsignedLong, (unsigned long))                       \
    API(long, PyLong_AsLong, (PyObject*))                                          \
    API(PyObject*, PyFloat_FromDouble, (double))                                   \
    API(double, PyFloat_AsDouble, (PyObject*))                                     \
    API(PyObject*, PyBool_FromLong, (long))                                        \
    API(PyObject*, PyBytes_FromStringAndSize, (const char*, Py_ssize_t_))          \
    API(int, PyBytes_AsStringAndSize, (PyObject*, char**, Py_ssize_t_*))           \
    API(PyObject*, PyErr_Occurred, (void))                                         \
    API(void, PyErr_Fetch, (PyObject**, PyObject**, PyObject**))                   \
    API(void, PyErr_Clear, (void))                                                 \
    API(PyObject*, PyDict_New, (void))                                             \
    API(PyObject*, PyDict_GetItemString, (PyObject*, const char*))
API_LIST
#undef API

static PyObject* py_none;      /* None */
static int api_ready = 0;       /* the table is filled and Python initialized */
static int api_started = 0;     /* and this library started the interpreter */
static char api_problem[8400];   /* why not, when it is not (under api_lock) */
/* Held while the API is resolved and Python started: the first
 * instantiation of a process may come from several threads at once. */
static pthread_mutex_t api_lock = PTHREAD_MUTEX_INITIALIZER;

static int resolve(void* handle)
{
#define API(ret, name, args)                                                       \
    p_##name = (ret(*) args)dlsym(handle, #name);                                  \
    if (!p_##name && strcmp(#name, "Py_SetPythonHome") != 0) {                     \
        snprintf(api_problem, sizeof api_problem, "the Python C API has no %s", #name); \
        return 0;                                                                  \
    }
    API_LIST
#undef API
    py_none = (PyObject*)dlsym(handle, "_Py_NoneStruct");
    if (!py_none) {
        snprintf(api_problem, sizeof api_problem, "the Python C API has no _Py_NoneStruct");
        return 0;
    }
    return 1;
}

/* A new reference to None. */
static PyObject* none(void)
{
    p_Py_IncRef(py_none);
    return py_none;
}

/* The next line of `f` into `out`, without its newline; 0 at the end of the file. */
static int read_line(FILE* f, char* out, size_t size)
{
    if (!fgets(out, (int)size, f)) return 0;
    size_t n = strlen(out);
    while (n && (out[n - 1] == '\n' || out[n - 1] == '\r')) out[--n] = '\0';
    return 1;
}

/* resources/hfdi_fmu_python.txt: the Python library (empty when the build's
 * Python has none, a static one), its home, the entry module; 0 with the
 * reason in `problem` when the file is missing or malformed. */
typedef struct { char library[4096], home[4096], entry[256]; } Description;

static int read_description(const char* resources, Description* d, char* problem,
                            size_t size)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/hfdi_fmu_python.txt", resources);
    FILE* f = fopen(path, "r");
    int ok = f && read_line(f, d->library, sizeof d->library)
             && read_line(f, d->home, sizeof d->home) && read_line(f, d->entry, sizeof d->entry)
             && d->entry[0];
    if (f) fclose(f);
    if (!ok) snprintf(problem, size, "the FMU's resources are damaged: %s is missing or "
                      "malformed", path);
    return ok;
}

/* Make the C API usable: the host's interpreter if it has one, else the
 * library the FMU was built with (its path and home in resources). With
 * api_lock held. */
static int start_python(const char* resources)
{
    if (api_ready) return 1;
    void* self = dlopen(NULL, RTLD_LAZY);
    int (*is_initialized)(void) = self ? (int (*)(void))dlsym(self, "Py_IsInitialized") : NULL;
    if (is_initialized && is_initialized()) {
        if (!resolve(self)) return 0;
        api_ready = 1;
        return 1;
    }
    Description d;
    if (!read_description(resources, &d, api_problem, sizeof api_problem)) return 0;
    if (!d.library[0]) {
        snprintf(api_problem, sizeof api_problem, "no Python in the host, and the FMU was built "
                 "with a Python that has no shared library to load");
        return 0;
    }
    const char* library = d.library;
    const char* home = d.home;
    void* lib = dlopen(library, RTLD_NOW | RTLD_GLOBAL);
    if (!lib) {
        snprintf(api_problem, sizeof api_problem, "cannot load the Python library %s: %s",
                 library, dlerror());
        return 0;
    }
    if (!resolve(lib)) return 0;
    if (!p_Py_IsInitialized()) {
        if (p_Py_SetPythonHome) {
            /* Py_SetPythonHome keeps the pointer: it lives as long as Python */
            wchar_t* whome = p_Py_DecodeLocale(home, NULL);
            if (whome) p_Py_SetPythonHome(whome);
        } else if (home[0]) {
            setenv("PYTHONHOME", home, 0);   /* Pythons without Py_SetPythonHome (3.13) */
        }
        /* Python's initialization sets LC_CTYPE from the environment; the
         * host's locale is the host's: put it back as it was */
        const char* current = setlocale(LC_ALL, NULL);
        char* host_locale = current ? strdup(current) : NULL;
        p_Py_InitializeEx(0);
        if (host_locale) {
            setlocale(LC_ALL, host_locale);
            free(host_locale);
        }
        if (!p_Py_IsInitialized()) {
            snprintf(api_problem, sizeof api_problem, "Python failed to initialize");
            return 0;
        }
        p_PyEval_SaveThread();   /* every call below takes the GIL itself */
        api_started = 1;
    }
    api_ready = 1;
    return 1;
}

/* start_python once per process, whatever the number of threads calling it
 * at once; 0 with the reason in `problem` when Python cannot be used. */
static int python_ready(const char* resources, char* problem, size_t size)
{
    pthread_mutex_lock(&api_lock);
    int ok = api_ready || start_python(resources);
    if (!ok) snprintf(problem, size, "%s", api_problem);
    pthread_mutex_unlock(&api_lock);
    return ok;
}

/* ---------------------------------------------------------------------------
 * The instance
 * ------------------------------------------------------------------------- */
/* ---------------------------------------------------------------------------
 * The native path: a doStep (and a read of the states) without Python.
 *
 * The Adapter owns the gate, an int64 array the slave fills when its
 * integrator runs in the compiled driver (entry.py, GATE_*): the address of
 * hfdi.compiled.NativeAdvance's C function and context, of the state's time
 * and of its arrays u, v, a, and a table from value references to entries
 * of those arrays and of the inputs F[i] (an entry -2 - i). While the gate
 * is armed (the arrays are the slave's state), a doStep calls the function
 * directly, a get of Float64 states reads the arrays and a set of inputs
 * writes the slave's inputs (the function holds them from the next step on,
 * as the slave does): none of them enters Python or takes the GIL. A call that
 * does enter Python first has the slave take over what the native steps did
 * (sync_native, when the gate is dirty) and, unless it only reads, disarms
 * the gate; the slave arms it again after a doStep of its own. A step the
 * function does not take (a breakpoint, a stop, the budget of internal
 * steps) changes nothing and is taken by the slave, so that every status and
 * message has one source. On the Python path (or while the gate cannot be
 * armed) the slave still opens it for reading: after its doStep it copies
 * u, v, a where the gate's state address points (readable, not armed).
 * ------------------------------------------------------------------------- */
enum { GATE_ARMED, GATE_DIRTY, GATE_FUNCTION, GATE_CONTEXT, GATE_TIME, GATE_STATE,
       GATE_INPUTS, GATE_TABLE, GATE_TABLE_LENGTH, GATE_CPU_NS, GATE_STEPS, GATE_READS,
       GATE_WRITES, GATE_READABLE, GATE_STOP, GATE_SIZE = 16 };
typedef int64_t (*NativeAdvance)(int64_t* context, double t_stop);

typedef struct Instance Instance;
/* Pass one message to the host's logger, in the FMI version's way. */
typedef void (*Emit)(const Instance* inst, int status, const char* category, const char* text);

struct Instance {
    char* name;
    Emit emit;                     /* the layer's: FMI 2.0 doubles every '%' */
    void* environment;             /* the host's: component or instance environment */
    void (*logger)(void);          /* the host's logger (the layer casts it back) */
    int logging_on;
    PyObject* adapter;             /* the entry module's Adapter */
    int64_t* gate;                 /* the Adapter's gate (see above), or NULL */
    char** strings;                /* what the last get of Strings returned */
    size_t n_strings;
    bool early_return;             /* FMI 3.0: instantiated with earlyReturnAllowed */
};

static char* copy_text(const char* text)
{
    size_t n = strlen(text ? text : "");
    char* out = (char*)malloc(n + 1);
    if (out) memcpy(out, text ? text : "", n + 1);
    return out;
}

static void logf_(const Instance* inst, int status, const char* format, ...)
{
    va_list ap, again;
    va_start(ap, format);
    va_copy(again, ap);
    int n = vsnprintf(NULL, 0, format, ap);
    va_end(ap);
    char* text = n >= 0 ? (char*)malloc((size_t)n + 1) : NULL;
    if (!text) {
        va_end(again);
        return;
    }
    vsnprintf(text, (size_t)n + 1, format, again);
    va_end(again);
    const char* category = status == ST_OK ? "logAll" :
                           status == ST_WARNING ? "logStatusWarning" :
                           status == ST_DISCARD ? "logStatusDiscard" :
                           status == ST_ERROR ? "logStatusError" : "logStatusFatal";
    if (inst->emit) inst->emit(inst, status, category, text);
    free(text);
}

/* Text of an object, UTF-8; "" when it has none. Borrowed storage inside `holder`. */
static const char* text_of(PyObject* obj, PyObject** holder)
{
    *holder = obj ? p_PyObject_Str(obj) : NULL;
    const char* s = *holder ? p_PyUnicode_AsUTF8AndSize(*holder, NULL) : NULL;
    if (!s) {
        p_PyErr_Clear();
        return "";
    }
    return s;
}

/* The pending exception as one log message; ST_ERROR. */
static int report_exception(Instance* inst, const char* function)
{
    PyObject *type = NULL, *value = NULL, *trace = NULL, *holder = NULL;
    p_PyErr_Fetch(&type, &value, &trace);
    const char* text = text_of(value ? value : type, &holder);
    /* the slave's refusals name the FMI function and the culprit themselves */
    if (*text) logf_(inst, ST_ERROR, "%s", text);
    else logf_(inst, ST_ERROR, "%s failed", function);
    if (holder) p_Py_DecRef(holder);
    if (type) p_Py_DecRef(type);
    if (value) p_Py_DecRef(value);
    if (trace) p_Py_DecRef(trace);
    return ST_ERROR;
}

/* A new tuple of the `n` new references `items` (stolen, also on failure);
 * NULL with an exception set when an item is NULL (it could not be made) or
 * the tuple cannot be made. */
static PyObject* pack(int n, PyObject** items)
{
    int complete = 1;
    for (int i = 0; i < n; i++) complete = complete && items[i];
    PyObject* tuple = complete ? p_PyTuple_New(n) : NULL;
    for (int i = 0; i < n; i++) {
        if (tuple) p_PyTuple_SetItem(tuple, i, items[i]);
        else if (items[i]) p_Py_DecRef(items[i]);
    }
    return tuple;
}

/* Release the GIL taken for `function`, leaving no exception behind: one
 * still pending makes the call's status ST_ERROR, with its log message. */
static int release(Instance* inst, PyGILState gil, const char* function,
                          int status)
{
    if (p_PyErr_Occurred()) status = report_exception(inst, function);
    p_PyGILState_Release(gil);
    return status;
}

/* Pass on the slave's queued log messages (Adapter.take_log): ST_WARNING when
 * one of them was a warning (the call that logged it returns fmi2Warning, as
 * the standard pairs them), else ST_OK. */
static int drain_log(Instance* inst)
{
    int warned = ST_OK;
    if (!inst->adapter) return warned;
    PyObject* take = p_PyObject_GetAttrString(inst->adapter, "take_log");
    PyObject* items = take ? p_PyObject_CallObject(take, NULL) : NULL;
    if (take) p_Py_DecRef(take);
    if (!items) {
        p_PyErr_Clear();
        return warned;
    }
    Py_ssize_t_ n = p_PyList_Size(items);
    if (n < 0) p_PyErr_Clear();
    for (Py_ssize_t_ i = 0; i < n; i++) {
        PyObject* item = p_PyList_GetItem(items, i);
        long status = p_PyLong_AsLong(p_PyTuple_GetItem(item, 0));
        const char* category = p_PyUnicode_AsUTF8AndSize(p_PyTuple_GetItem(item, 1), NULL);
        const char* message = p_PyUnicode_AsUTF8AndSize(p_PyTuple_GetItem(item, 2), NULL);
        if (!category || !message || status < 0 || status > ST_PENDING) {
            p_PyErr_Clear();
            continue;
        }
        if (status == ST_WARNING) warned = ST_WARNING;
        if (status == ST_OK && !inst->logging_on) continue;
        if (inst->emit) inst->emit(inst, (int)status, category, message);
    }
    p_Py_DecRef(items);
    return warned;
}

/* The calls of the slave that only read its state: the gate stays armed. */
static int reads_only(const char* method)
{
    static const char* readers[] = {"get_real", "get_integer", "get_boolean", "get_string",
                                    "get_state", "serialize", "time", NULL};
    for (int i = 0; readers[i]; i++)
        if (strcmp(method, readers[i]) == 0) return 1;
    return 0;
}

/* adapter.<method>(*args): the result (new reference) or NULL with the
 * exception reported. `args` is a new reference to a tuple (or NULL), consumed.
 * With the GIL held. */
static PyObject* invoke(Instance* inst, const char* method, PyObject* args, int* status)
{
    int64_t* gate = inst->gate;
    int64_t armed = 0, readable = 0;
    if (gate) {
        if (gate[GATE_DIRTY]) {
            /* the slave takes over the native steps before anything else */
            PyObject* synced = p_PyObject_GetAttrString(inst->adapter, "sync_native");
            PyObject* done = synced ? p_PyObject_CallObject(synced, NULL) : NULL;
            if (synced) p_Py_DecRef(synced);
            if (done) p_Py_DecRef(done);
            else {
                gate[GATE_ARMED] = gate[GATE_DIRTY] = 0;
                *status = report_exception(inst, "sync_native");
                drain_log(inst);
                if (args) p_Py_DecRef(args);
                return NULL;
            }
        }
        armed = gate[GATE_ARMED];
        readable = gate[GATE_READABLE];
        gate[GATE_ARMED] = gate[GATE_READABLE] = 0;
    }
    PyObject* bound = p_PyObject_GetAttrString(inst->adapter, method);
    PyObject* result = bound ? p_PyObject_CallObject(bound, args) : NULL;
    if (bound) p_Py_DecRef(bound);
    if (args) p_Py_DecRef(args);
    if (gate && result && reads_only(method)) {
        gate[GATE_ARMED] = armed;
        gate[GATE_READABLE] = readable;
    }
    if (!result) *status = report_exception(inst, method);
    if (drain_log(inst) == ST_WARNING && result && *status == ST_OK) *status = ST_WARNING;
    return result;
}

static int64_t cpu_ns(void)
{
    struct timespec now;
    if (clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &now) != 0) return 0;
    return (int64_t)now.tv_sec * 1000000000 + now.tv_nsec;
}

/* doStep(t, h) on the native path: 1 when taken, 0 when the slave must take it
 * (the gate is not armed, t is not the FMU's time, or the function did not
 * take the step: then nothing changed). The tests of t and h are the slave's,
 * which also says why when it refuses. */
static int native_step(Instance* inst, double t, double h)
{
    int64_t* gate = inst->gate;
    if (!gate || !gate[GATE_ARMED]) return 0;
    double here = *(const double*)(intptr_t)gate[GATE_TIME];
    if (!(isfinite(t) && isfinite(h) && h > 0.0)) return 0;
    double larger = fabs(t) > fabs(here) ? fabs(t) : fabs(here);
    double ulp = nextafter(larger, INFINITY) - larger;
    double tolerance = 64.0 * ulp > 1e-10 * h ? 64.0 * ulp : 1e-10 * h;
    if (!(fabs(t - here) <= tolerance)) return 0;
    double t_end = t + h;
    if (!(t_end > here && isfinite(t_end))) return 0;
    /* past the experiment's stop time (the slave's _stop_limit, with the
     * slack of the time above): the slave refuses it, fmi2Error */
    const double* stop_limit = (const double*)(intptr_t)gate[GATE_STOP];
    if (stop_limit && t_end > *stop_limit + 1e-10 * h) return 0;
    NativeAdvance advance = (NativeAdvance)(intptr_t)gate[GATE_FUNCTION];
    int64_t started = cpu_ns();
    int64_t taken = advance((int64_t*)(intptr_t)gate[GATE_CONTEXT], t_end);
    gate[GATE_CPU_NS] += cpu_ns() - started;
    if (taken != 1) return 0;
    gate[GATE_DIRTY] = 1;
    gate[GATE_STEPS] += 1;
    return 1;
}

/* A set of Float64 inputs on the native path: 1 when every reference is an
 * input (values written into the slave's inputs), else 0. */
static int native_write(Instance* inst, const ValueReference vr[], size_t nvr,
                        const double in[])
{
    int64_t* gate = inst->gate;
    if (!gate || !gate[GATE_ARMED] || !gate[GATE_INPUTS]) return 0;
    const int64_t* table = (const int64_t*)(intptr_t)gate[GATE_TABLE];
    int64_t length = gate[GATE_TABLE_LENGTH];
    for (size_t i = 0; i < nvr; i++)
        if ((int64_t)vr[i] >= length || table[vr[i]] > -2) return 0;
    double* inputs = (double*)(intptr_t)gate[GATE_INPUTS];
    for (size_t i = 0; i < nvr; i++) inputs[-2 - table[vr[i]]] = in[i];
    gate[GATE_WRITES] += 1;
    return 1;
}

/* A get of Float64 states on the native path: 1 when every reference is a
 * state entry the gate's table knows (values written), else 0. */
static int native_read(Instance* inst, const ValueReference vr[], size_t nvr,
                       double out[])
{
    int64_t* gate = inst->gate;
    if (!gate || !gate[GATE_READABLE]) return 0;
    const int64_t* table = (const int64_t*)(intptr_t)gate[GATE_TABLE];
    int64_t length = gate[GATE_TABLE_LENGTH];
    for (size_t i = 0; i < nvr; i++)
        if ((int64_t)vr[i] >= length || table[vr[i]] < 0) return 0;
    const double* state = (const double*)(intptr_t)gate[GATE_STATE];
    for (size_t i = 0; i < nvr; i++) out[i] = state[table[vr[i]]];
    gate[GATE_READS] += 1;
    return 1;
}

#define INSTANCE_OR_ERROR(c)                                                       \
    Instance* inst = (Instance*)(c);                                               \
    if (!inst || !api_ready || !inst->adapter) return ST_ERROR;

/* A call with no result but its success. */
static int simple(void* c, const char* method, PyObject* (*make_args)(void*),
                         void* data)
{
    INSTANCE_OR_ERROR(c)
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* args = make_args ? make_args(data) : NULL;
    if (make_args && !args) return release(inst, gil, method, ST_ERROR);
    PyObject* result = invoke(inst, method, args, &status);
    if (result) p_Py_DecRef(result);
    return release(inst, gil, method, status);
}

/* ---------------------------------------------------------------------------
 * Instantiation
 * ------------------------------------------------------------------------- */
static void free_strings(Instance* inst)
{
    for (size_t i = 0; i < inst->n_strings; i++) free(inst->strings[i]);
    free(inst->strings);
    inst->strings = NULL;
    inst->n_strings = 0;
}

static void free_instance(Instance* inst)
{
    if (!inst) return;
    free_strings(inst);
    free(inst->name);
    free(inst);
}

/* The entry module (resources/<name>.py) is run as module <name> once per
 * process, by this function of Python, after a check that its bytes give
 * the digest its name ends with. Not imported through sys.path: the host's
 * import path stays as it is, and the entry imports the FMU's other modules
 * under private names (fmu/entry.py). Two threads may run the file at once;
 * sys.modules keeps the first module finished, which every instance uses. */
static const char ENTRY_LOADER[] =
    "def load(name, path):\n"
    "    import hashlib, sys, types\n"
    "    module = sys.modules.get(name)\n"
    "    if module is not None:\n"
    "        return module\n"
    "    with open(path, 'rb') as f:\n"
    "        source = f.read()\n"
    "    if hashlib.sha256(source + bytes(1)).hexdigest()[:12] != name.rpartition('_')[2]:\n"
    "        raise ImportError(f\"the FMU's resources are damaged: {path} is not the file \"\n"
    "                          \"its name says\")\n"
    "    module = types.ModuleType(name)\n"
    "    module.__file__ = path\n"
    "    exec(compile(source, path, 'exec', dont_inherit=True), module.__dict__)\n"
    "    return sys.modules.setdefault(name, module)\n";
static PyObject* entry_loader = NULL;   /* load, made once (with the GIL held) */

/* The entry module (a new reference), or NULL with an exception set. With the GIL held. */
static PyObject* load_entry(const char* resources, const char* name)
{
    if (!entry_loader) {
        PyObject* builtins = p_PyImport_ImportModule("builtins");
        PyObject* run = builtins ? p_PyObject_GetAttrString(builtins, "exec") : NULL;
        PyObject* globals = p_PyDict_New();
        if (globals) p_Py_IncRef(globals);
        PyObject* items[2] = {p_PyUnicode_DecodeUTF8(ENTRY_LOADER,
                                                     (Py_ssize_t_)strlen(ENTRY_LOADER), "strict"),
                              globals};
        PyObject* args = pack(2, items);
        PyObject* done = run && args ? p_PyObject_CallObject(run, args) : NULL;
        PyObject* load = done ? p_PyDict_GetItemString(globals, "load") : NULL;   /* borrowed */
        if (load && !entry_loader) {     /* another thread may have made it meanwhile */
            p_Py_IncRef(load);
            entry_loader = load;
        }
        if (done) p_Py_DecRef(done);
        if (args) p_Py_DecRef(args);
        if (globals) p_Py_DecRef(globals);
        if (run) p_Py_DecRef(run);
        if (builtins) p_Py_DecRef(builtins);
        if (!entry_loader) return NULL;
    }
    size_t n = strlen(resources) + strlen(name) + 5;
    char* path = (char*)malloc(n);
    if (!path) return NULL;
    snprintf(path, n, "%s/%s.py", resources, name);
    PyObject* items[2] = {p_PyUnicode_DecodeUTF8(name, (Py_ssize_t_)strlen(name), "strict"),
                          p_PyUnicode_DecodeFSDefault(path)};
    free(path);
    PyObject* args = pack(2, items);
    PyObject* module = args ? p_PyObject_CallObject(entry_loader, args) : NULL;
    if (args) p_Py_DecRef(args);
    return module;
}

/* The references as a new list, or NULL with an exception set. */
static PyObject* references(const ValueReference vr[], size_t nvr)
{
    PyObject* list = p_PyList_New((Py_ssize_t_)nvr);
    for (size_t i = 0; list && i < nvr; i++) {
        PyObject* item = p_PyLong_FromUnsignedLong(vr[i]);
        if (!item) {
            p_Py_DecRef(list);
            return NULL;
        }
        p_PyList_SetItem(list, (Py_ssize_t_)i, item);
    }
    return list;
}

/* The kinds of values: Real or Float64 (double), Integer or Int32 (int),
 * FMI 2.0's Boolean (int), FMI 3.0's Boolean (bool), String. */
typedef enum { REAL, INTEGER, BOOLEAN_INT, BOOLEAN_BYTE, STRING } Kind;
static const char* GETTERS[] = {"get_real", "get_integer", "get_boolean", "get_boolean",
                                "get_string"};
static const char* SETTERS[] = {"set_real", "set_integer", "set_boolean", "set_boolean",
                                "set_string"};

/* The most values one get or set may name (2^24, a tenth of a gigabyte of
 * Reals): a larger nvr is a master's mistake (a negative count turned into
 * size_t, say) and is refused before either array is read. */
#define MAX_VALUES ((size_t)1 << 24)

/* 1 when the arrays of a get or set may be read, else 0 after a log message. */
static int arrays_ok(Instance* inst, const char* function, const ValueReference vr[],
                     size_t nvr, const void* values)
{
    if (!vr || !values) {
        logf_(inst, ST_ERROR, "%s: NULL array", function);
        return 0;
    }
    if (nvr > MAX_VALUES) {
        logf_(inst, ST_ERROR, "%s: nvr = %zu values in one call, more than the %zu a call "
              "may name", function, nvr, MAX_VALUES);
        return 0;
    }
    return 1;
}

static int get_values(void* c, const char* function, Kind kind, const ValueReference vr[],
                             size_t nvr, void* out)
{
    INSTANCE_OR_ERROR(c)
    if (nvr == 0) return ST_OK;
    if (!arrays_ok(inst, function, vr, nvr, out)) return ST_ERROR;
    if (kind == REAL && native_read(inst, vr, nvr, (double*)out)) return ST_OK;
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* items[1] = {references(vr, nvr)};
    PyObject* args = pack(1, items);
    if (!args) return release(inst, gil, function, ST_ERROR);
    PyObject* values = invoke(inst, GETTERS[kind], args, &status);
    if (values) {
        if (kind == STRING) free_strings(inst);
        if (p_PyList_Size(values) != (Py_ssize_t_)nvr) {
            p_PyErr_Clear();
            logf_(inst, ST_ERROR, "%s: wrong number of values", function);
            status = ST_ERROR;
        } else if (kind == STRING) {
            inst->strings = (char**)calloc(nvr, sizeof(char*));
            inst->n_strings = inst->strings ? nvr : 0;
        }
        for (size_t i = 0; status == ST_OK && i < nvr; i++) {
            PyObject* item = p_PyList_GetItem(values, (Py_ssize_t_)i);
            switch (kind) {
            case REAL: ((double*)out)[i] = p_PyFloat_AsDouble(item); break;
            case INTEGER: ((int*)out)[i] = (int)p_PyLong_AsLong(item); break;
            case BOOLEAN_INT: ((int*)out)[i] = p_PyObject_IsTrue(item) == 1; break;
            case BOOLEAN_BYTE: ((bool*)out)[i] = p_PyObject_IsTrue(item) == 1; break;
            case STRING: {
                const char* s = p_PyUnicode_AsUTF8AndSize(item, NULL);
                if (s && inst->strings) inst->strings[i] = copy_text(s);
                ((const char**)out)[i] = inst->strings && inst->strings[i] ? inst->strings[i] : "";
                break;
            }
            }
            if (p_PyErr_Occurred()) status = report_exception(inst, function);
        }
        p_Py_DecRef(values);
    }
    return release(inst, gil, function, status);
}

static int set_values(void* c, const char* function, Kind kind, const ValueReference vr[],
                             size_t nvr, const void* in)
{
    INSTANCE_OR_ERROR(c)
    if (nvr == 0) return ST_OK;
    if (!arrays_ok(inst, function, vr, nvr, in)) return ST_ERROR;
    if (kind == REAL && native_write(inst, vr, nvr, (const double*)in)) return ST_OK;
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* values = p_PyList_New((Py_ssize_t_)nvr);
    for (size_t i = 0; values && i < nvr; i++) {
        PyObject* item = NULL;
        switch (kind) {
        case REAL: item = p_PyFloat_FromDouble(((const double*)in)[i]); break;
        case INTEGER: item = p_PyLong_FromLong(((const int*)in)[i]); break;
        case BOOLEAN_INT: item = p_PyBool_FromLong(((const int*)in)[i] != 0); break;
        /* as bytes: a host's value other than 0 and 1 is true, not undefined */
        case BOOLEAN_BYTE: item = p_PyBool_FromLong(((const unsigned char*)in)[i] != 0); break;
        case STRING: {
            const char* s = ((const char* const*)in)[i];
            item = s ? p_PyUnicode_DecodeUTF8(s, (Py_ssize_t_)strlen(s), "strict") : NULL;
            if (!item) {
                p_PyErr_Clear();
                logf_(inst, ST_ERROR, "%s: value %zu (reference %u) is %s; no value "
                      "was set", function, i + 1, (unsigned)vr[i], s ? "not UTF-8 text" : "NULL");
                status = ST_ERROR;
            }
            break;
        }
        }
        if (!item) {
            p_Py_DecRef(values);
            values = NULL;
            break;
        }
        p_PyList_SetItem(values, (Py_ssize_t_)i, item);
    }
    if (status == ST_OK) {
        /* values NULL: the list or an item could not be made (the exception
           is reported by release, nothing was set) */
        PyObject* items[2] = {values ? references(vr, nvr) : NULL, values};
        PyObject* args = values ? pack(2, items) : NULL;
        if (args) {
            PyObject* result = invoke(inst, SETTERS[kind], args, &status);
            if (result) p_Py_DecRef(result);
        } else {
            status = report_exception(inst, function);
        }
    } else if (values) {
        p_Py_DecRef(values);
    }
    return release(inst, gil, function, status);
}

/* ---------------------------------------------------------------------------
 * FMU states: a new reference to the Python object the slave returns.
 *
 * Every state handed out is recorded (process-wide: a state may be restored
 * into another instance of this FMU) until it is freed; a pointer that
 * is not a live state -- freed, or never one -- is refused before it is
 * touched, so a master's use of a freed state gets ST_ERROR, not the
 * host's crash. The list is only read or changed with the GIL held.
 * ------------------------------------------------------------------------- */
static void** live_states = NULL;
static size_t n_live = 0, live_capacity = 0;

static int state_is_live(const void* state)
{
    for (size_t i = 0; i < n_live; i++)
        if (live_states[i] == state) return 1;
    return 0;
}

static int track_state(void* state)
{
    if (n_live == live_capacity) {
        size_t capacity = live_capacity ? 2 * live_capacity : 16;
        void** grown = (void**)realloc(live_states, capacity * sizeof(void*));
        if (!grown) return 0;
        live_states = grown;
        live_capacity = capacity;
    }
    live_states[n_live++] = state;
    return 1;
}

static int untrack_state(const void* state)
{
    for (size_t i = 0; i < n_live; i++)
        if (live_states[i] == state) {
            live_states[i] = live_states[--n_live];
            return 1;
        }
    return 0;
}

/* Hand `fresh` (a new reference) to the master in *state, replacing a live
 * state given there (FMI 2.0: an existing state is overwritten). */
static int give_state(Instance* inst, const char* function, PyObject* fresh, void** state)
{
    if (!track_state(fresh)) {
        p_Py_DecRef(fresh);
        logf_(inst, ST_ERROR, "%s: out of memory", function);
        return ST_ERROR;
    }
    if (*state && untrack_state(*state)) p_Py_DecRef((PyObject*)*state);
    *state = fresh;
    return ST_OK;
}

static int live_or_log(Instance* inst, const char* function, void* state)
{
    if (state && state_is_live(state)) return 1;
    logf_(inst, ST_ERROR, "%s: the state is %s", function,
          state ? "not a live FMU state (freed, or never made by this FMU's get or "
                  "deserialize of an FMU state)" : "NULL");
    return 0;
}

/* A NULL pointer argument of `function`: ST_ERROR after a log message. */
static int null_argument(Instance* inst, const char* function, const char* what)
{
    logf_(inst, ST_ERROR, "%s: %s is NULL", function, what);
    return ST_ERROR;
}

/* A new tuple of one new reference to `state`, or NULL with an exception set. */
static PyObject* state_args(void* state)
{
    p_Py_IncRef((PyObject*)state);
    PyObject* items[1] = {(PyObject*)state};
    return pack(1, items);
}

static int state_get(void* c, const char* function, void** state)
{
    INSTANCE_OR_ERROR(c)
    if (!state) return null_argument(inst, function, "the FMU state pointer");
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* saved = invoke(inst, "get_state", NULL, &status);
    if (saved) status = give_state(inst, function, saved, state);
    return release(inst, gil, function, status);
}

static int state_set(void* c, const char* function, void* state)
{
    INSTANCE_OR_ERROR(c)
    PyGILState gil = p_PyGILState_Ensure();
    if (!live_or_log(inst, function, state)) return release(inst, gil, function, ST_ERROR);
    int status = ST_OK;
    PyObject* args = state_args(state);
    PyObject* result = args ? invoke(inst, "set_state", args, &status) : NULL;
    if (result) p_Py_DecRef(result);
    return release(inst, gil, function, args ? status : ST_ERROR);
}

static int state_free(void* c, const char* function, void** state)
{
    INSTANCE_OR_ERROR(c)
    if (!state || !*state) return ST_OK;
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    if (untrack_state(*state)) p_Py_DecRef((PyObject*)*state);
    else {
        logf_(inst, ST_ERROR, "%s: the state is not a live FMU state (freed already, or never "
              "made by this FMU's get or deserialize of an FMU state)", function);
        status = ST_ERROR;
    }
    *state = NULL;
    return release(inst, gil, function, status);
}

/* The serialized state (new reference to bytes), or NULL with the status set. */
static PyObject* serialized(Instance* inst, const char* function, void* state, int* status)
{
    PyObject* args = state_args(state);
    if (!args) {
        *status = report_exception(inst, function);
        return NULL;
    }
    return invoke(inst, "serialize", args, status);
}

static int state_size(void* c, const char* function, void* state, size_t* size)
{
    INSTANCE_OR_ERROR(c)
    if (!size) return null_argument(inst, function, "the size pointer");
    PyGILState gil = p_PyGILState_Ensure();
    if (!live_or_log(inst, function, state)) return release(inst, gil, function, ST_ERROR);
    int status = ST_OK;
    PyObject* bytes = serialized(inst, function, state, &status);
    char* data;
    Py_ssize_t_ n;
    if (bytes && p_PyBytes_AsStringAndSize(bytes, &data, &n) == 0) *size = (size_t)n;
    else if (bytes) status = report_exception(inst, function);
    if (bytes) p_Py_DecRef(bytes);
    return release(inst, gil, function, status);
}

static int state_serialize(void* c, const char* function, void* state, char out[],
                           size_t size)
{
    INSTANCE_OR_ERROR(c)
    if (!out) return null_argument(inst, function, "the buffer");
    PyGILState gil = p_PyGILState_Ensure();
    if (!live_or_log(inst, function, state)) return release(inst, gil, function, ST_ERROR);
    int status = ST_OK;
    PyObject* bytes = serialized(inst, function, state, &status);
    char* data;
    Py_ssize_t_ n;
    if (bytes && p_PyBytes_AsStringAndSize(bytes, &data, &n) == 0) {
        if ((size_t)n != size) {
            logf_(inst, ST_ERROR, "%s: the buffer has %zu bytes, the state %zu", function,
                  size, (size_t)n);
            status = ST_ERROR;
        } else {
            memcpy(out, data, size);
        }
    } else if (bytes) {
        status = report_exception(inst, function);
    }
    if (bytes) p_Py_DecRef(bytes);
    return release(inst, gil, function, status);
}

/* The largest size a Python bytes object can have (PY_SSIZE_T_MAX). */
#define MAX_BYTES ((size_t)(SIZE_MAX >> 1))

static int state_deserialize(void* c, const char* function, const char data[], size_t size,
                             void** state)
{
    INSTANCE_OR_ERROR(c)
    if (!state) return null_argument(inst, function, "the FMU state pointer");
    if (!data && size) return null_argument(inst, function, "the data");
    if (size > MAX_BYTES) {
        logf_(inst, ST_ERROR, "%s: size = %zu bytes is more than any serialized state has",
              function, size);
        return ST_ERROR;
    }
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* items[1] = {p_PyBytes_FromStringAndSize(data ? data : "", (Py_ssize_t_)size)};
    PyObject* args = pack(1, items);
    if (!args) return release(inst, gil, function, ST_ERROR);
    PyObject* restored = invoke(inst, "deserialize", args, &status);
    if (restored) status = give_state(inst, function, restored, state);
    return release(inst, gil, function, status);
}

/* ---------------------------------------------------------------------------
 * Instantiation, the experiment, stepping
 * ------------------------------------------------------------------------- */
/* A new instance named `name` logging through `emit`; NULL without memory. */
static Instance* new_instance(const char* name, Emit emit, void* environment,
                              void (*logger)(void), int logging_on)
{
    Instance* inst = (Instance*)calloc(1, sizeof(Instance));
    if (!inst) return NULL;
    inst->name = copy_text(name);
    inst->emit = emit;
    inst->environment = environment;
    inst->logger = logger;
    inst->logging_on = logging_on;
    return inst;
}

/* Make the slave of the FMU in `resources` (a folder): Python started, the
 * entry module loaded, the GUID or instantiation token checked; 1, or 0
 * after one log message naming `function`. */
static int instantiate_slave(Instance* inst, const char* function, const char* resources,
                             const char* guid, int visible, int logging_on)
{
    char problem[8400];
    Description d;
    if (!python_ready(resources, problem, sizeof problem)
        || !read_description(resources, &d, problem, sizeof problem)) {
        logf_(inst, ST_ERROR, "%s: %s", function, problem);
        return 0;
    }
    PyGILState gil = p_PyGILState_Ensure();
    PyObject *entry = load_entry(resources, d.entry), *make = NULL, *args = NULL;
    if (entry) make = p_PyObject_GetAttrString(entry, "instantiate");
    if (make) {
        guid = guid ? guid : "";
        PyObject* items[6] = {
            p_PyUnicode_DecodeFSDefault(resources),
            p_PyUnicode_DecodeUTF8(inst->name, (Py_ssize_t_)strlen(inst->name), "replace"),
            p_PyUnicode_DecodeUTF8(guid, (Py_ssize_t_)strlen(guid), "replace"),
            p_PyBool_FromLong(visible != 0), p_PyBool_FromLong(logging_on != 0),
            p_PyBool_FromLong(api_started)};
        args = pack(6, items);
        if (args) inst->adapter = p_PyObject_CallObject(make, args);
    }
    if (!inst->adapter) report_exception(inst, function);
    else {
        /* the gate of the native path (0: none; no gate is no error) */
        PyObject* bound = p_PyObject_GetAttrString(inst->adapter, "native_gate");
        PyObject* address = bound ? p_PyObject_CallObject(bound, NULL) : NULL;
        if (bound) p_Py_DecRef(bound);
        if (address) {
            long value = p_PyLong_AsLong(address);
            if (value > 0 && !p_PyErr_Occurred()) inst->gate = (int64_t*)(intptr_t)value;
            p_Py_DecRef(address);
        }
        p_PyErr_Clear();
    }
    if (args) p_Py_DecRef(args);
    if (make) p_Py_DecRef(make);
    if (entry) p_Py_DecRef(entry);
    if (inst->adapter) drain_log(inst);
    p_PyErr_Clear();
    p_PyGILState_Release(gil);
    return inst->adapter != NULL;
}

static void release_instance(Instance* inst)
{
    if (!inst) return;
    if (api_ready && inst->adapter) {
        PyGILState gil = p_PyGILState_Ensure();
        p_Py_DecRef(inst->adapter);
        p_PyGILState_Release(gil);
    }
    free_instance(inst);
}

typedef struct { int tol_defined; double tol; double start; int stop_defined; double stop; } Setup;

static PyObject* setup_args(void* data)
{
    Setup* s = (Setup*)data;
    PyObject* items[3] = {p_PyFloat_FromDouble(s->start),
                          s->stop_defined ? p_PyFloat_FromDouble(s->stop) : none(),
                          s->tol_defined ? p_PyFloat_FromDouble(s->tol) : none()};
    return pack(3, items);
}

typedef struct { double t, h; int early; } Step;

/* do_step(t, h) of the slave; *early and *last (when not NULL) from
 * do_step_early(t, h, allowed) instead: whether it returned early, and the
 * FMU's time after it (where a discarded step left it, too). */
static int do_step(void* c, const char* function, double t, double h, int early_allowed,
                   bool* early, double* last)
{
    INSTANCE_OR_ERROR(c)
    if (early) *early = false;
    if (native_step(inst, t, h)) {
        if (last) *last = t + h;
        return ST_OK;
    }
    PyGILState gil = p_PyGILState_Ensure();
    int status = ST_OK;
    PyObject* items[3] = {p_PyFloat_FromDouble(t), p_PyFloat_FromDouble(h),
                          p_PyBool_FromLong(early_allowed != 0)};
    PyObject* args = pack(early ? 3 : 2, items);
    if (!early) p_Py_DecRef(items[2]);
    if (!args) return release(inst, gil, function, ST_ERROR);
    PyObject* taken = invoke(inst, early ? "do_step_early" : "do_step", args, &status);
    if (taken && early) {
        int ok = p_PyObject_IsTrue(p_PyTuple_GetItem(taken, 0));
        int returned = p_PyObject_IsTrue(p_PyTuple_GetItem(taken, 1));
        double time = p_PyFloat_AsDouble(p_PyTuple_GetItem(taken, 2));
        p_Py_DecRef(taken);
        if (p_PyErr_Occurred()) status = report_exception(inst, function);
        else {
            *early = returned == 1;
            if (last) *last = time;
            if (ok != 1) status = ST_DISCARD;
        }
    } else if (taken) {
        int ok = p_PyObject_IsTrue(taken);
        p_Py_DecRef(taken);
        if (ok != 1) status = ok == 0 ? ST_DISCARD : report_exception(inst, function);
    }
    return release(inst, gil, function, status);
}

/* A function that does not apply to this FMU: ST_ERROR and one log line. */
static int not_provided(void* c, const char* function, const char* why)
{
    Instance* inst = (Instance*)c;
    if (inst) logf_(inst, ST_ERROR, "%s is not provided%s%s", function, why ? ": " : "",
                    why ? why : "");
    return ST_ERROR;
}

#endif
