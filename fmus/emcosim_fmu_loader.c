/* The binary of every emcosim FMU: binaries/linux64/<modelIdentifier>.so (built by build.py).
 *
 * pythonfmu 0.7.0's export library (shipped beside this file as libpythonfmu-export.so) runs the FMU's
 * Python slave, but it expects a host that already has Python: its Python C-API symbols are undefined,
 * so a plain C host fails at dlopen, and a host that preloads libpython still has to point Python at
 * numpy and scipy. It answers "not supported" to the three derivative functions, turns every Python
 * exception into fmi2Fatal (releasing the slave once too often: two failed calls and the host crashes),
 * returns fmi2OK for whatever a setter refuses, and forwards log messages only with loggingOn. This loader:
 *
 *  1. Python. If the process has a running Python (fmpy, libcosimpy: dlsym(RTLD_DEFAULT,
 *     "Py_IsInitialized")), that one is used, as by pythonfmu alone. Otherwise fmi2Instantiate loads the
 *     libpython recorded by build.py in resources/emcosim_fmu.txt with RTLD_GLOBAL and starts it with the
 *     recorded interpreter as sys.executable, so that the site-packages of its environment (numpy, scipy)
 *     are found. EMCOSIM_FMU_PYTHON (an interpreter of the same Python version) overrides the record.
 *     When that Python is missing or unusable, fmi2Instantiate logs one message saying what is missing
 *     and which variable to set, and returns NULL.
 *  2. Checks, before pythonfmu's code runs: numpy and scipy import, and no module of this FMU's names (its
 *     bundle package emcosim_fmu_<tag>, its script) is already loaded from another build: fmi2Instantiate
 *     refuses a clash with one message.
 *  3. Creates the instance with pythonfmu's library (always as a Co-Simulation one: pythonfmu has no Model
 *     Exchange; the slave is told the host's fmuType), then answers every FMI call of an emcosim slave
 *     itself by calling the slave's fmi2_* methods (fmus/slave.py: EMSlave) with the GIL held: they
 *     return (status, ..., message) and never raise, so a bad argument or a call in the wrong state gets
 *     fmi2Error with a message, FMU states are checked before use, and the three derivative functions and
 *     the Model Exchange functions are answered. Only fmi2Instantiate, fmi2Reset and fmi2FreeInstance go
 *     to pythonfmu's library (and every call of a slave that is not an emcosim one, e.g. the benchmark's
 *     floor).
 *  4. Keeps a registry of its live instances and of the FMU states they gave out: a call with a NULL,
 *     unknown or freed instance (a second fmi2FreeInstance) or state is refused, not followed.
 *  5. Logs through the host's logger: warnings and errors always, other messages with loggingOn.
 *  6. Checks every argument of an FMI call before it reads an element of an array (issue 31, item 2): the
 *     instance, every pointer (NULL with a count > 0), and every count against the FMU's own numbers, which
 *     the slave tells at fmi2Instantiate (fmi2_get_sizes): nx and ni must equal the numbers of continuous
 *     states and event indicators (FMI 2.0 fixes them), nvr, nUnknown and nKnown may not exceed the number
 *     of variables of the call's type (none for Boolean and String; the derivative functions: times
 *     maxOutputDerivativeOrder, or INPUT_ORDERS_PER_CALL for input derivatives), a serialized state's size
 *     must be the length its header states (fmus/state.py). A wrong count gets fmi2Error and one message;
 *     nothing of the host's arrays is read. (No FMU can see the length of a host's array: a count within
 *     these bounds is trusted.) The value references themselves and the state machine are checked by the
 *     slave, before any value is used.
 *
 * The interpreter the loader starts is never finalized: Py_Finalize at process exit is what crashed C
 * hosts before (docs/reliability.md, finding 1), other FMUs of the process may still use it, and numpy
 * cannot be initialized twice in one process. Python's stdio is unbuffered so that nothing is lost.
 *
 * Links libc and libdl only: every Python function is looked up with dlsym at run time (Python.h gives
 * the types; build.py checks that the binary has no undefined Python symbol).
 */
#include <Python.h>

#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fmi2Functions.h"

#define OVERRIDE_VARIABLE "EMCOSIM_FMU_PYTHON"
#define RECORD_FILE "emcosim_fmu.txt"
#define PYTHONFMU_LIBRARY "libpythonfmu-export.so"
#define MESSAGE_SIZE 2048

/* ---- the Python C API, looked up at run time ------------------------------------------------------ */
#define PY_FUNCTIONS(X)                                                                                   \
    X(Py_IsInitialized) X(Py_GetVersion) X(PyConfig_InitIsolatedConfig) X(PyConfig_SetBytesString)        \
    X(PyConfig_Clear) X(Py_InitializeFromConfig) X(PyStatus_Exception) X(PyEval_SaveThread)               \
    X(PyGILState_Ensure) X(PyGILState_Release) X(PyImport_ImportModule) X(PyImport_GetModule)             \
    X(PyObject_GetAttrString) X(PyObject_CallFunctionObjArgs) X(PyObject_Str) X(Py_IncRef) X(Py_DecRef)   \
    X(PyErr_Fetch) X(PyErr_Occurred) X(PyErr_Clear) X(PyList_New) X(PyList_SetItem) X(PyList_Size)        \
    X(PyList_GetItem) X(PyList_GetSlice) X(PyList_SetSlice) X(PyTuple_Size) X(PyTuple_GetItem) X(PyLong_FromLong)            \
    X(PyLong_FromUnsignedLong) X(PyLong_AsLong) X(PyFloat_FromDouble) X(PyFloat_AsDouble)                 \
    X(PyUnicode_FromString) X(PyUnicode_AsUTF8) X(PyBytes_FromStringAndSize) X(PyBytes_Size)              \
    X(PyBytes_AsString)

static struct {
#define DECLARE(name) __typeof__(&name) name;
    PY_FUNCTIONS(DECLARE)
#undef DECLARE
} py;

static const char *bind_python(void *library)
{
#define BIND(name)                                                                                        \
    if ((py.name = (__typeof__(py.name))dlsym(library, #name)) == NULL) return #name;
    PY_FUNCTIONS(BIND)
#undef BIND
    return NULL;
}

/* ---- pythonfmu's library -------------------------------------------------------------------------- */
#define FORWARDED(X)                                                                                      \
    X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetDebugLogging) X(fmi2SetupExperiment)                  \
    X(fmi2EnterInitializationMode) X(fmi2ExitInitializationMode) X(fmi2Terminate) X(fmi2Reset)            \
    X(fmi2GetReal) X(fmi2GetInteger) X(fmi2GetBoolean) X(fmi2GetString) X(fmi2SetReal) X(fmi2SetInteger)  \
    X(fmi2SetBoolean) X(fmi2SetString) X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate)          \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate) X(fmi2DoStep)       \
    X(fmi2CancelStep) X(fmi2GetStatus) X(fmi2GetRealStatus) X(fmi2GetIntegerStatus)                       \
    X(fmi2GetBooleanStatus) X(fmi2GetStringStatus)

static struct {
#define DECLARE(name) name##TYPE *name;
    FORWARDED(DECLARE)
#undef DECLARE
    void (*finalizePythonInterpreter)(void);
} lib;

extern int __cxa_atexit(void (*function)(void *), void *argument, void *dso_handle);

/* ---- state of the process: one for all emcosim FMUs -------------------------------------------------- */
/* Every FMU ships its own copy of this library, and a host loads each copy on its own (RTLD_LOCAL): a
 * static lock would be one per FMU, and two different FMUs instantiated at once from two threads started
 * Python twice at the same time (issue 26, item 7: SIGSEGV, "double free or corruption"). Every copy has
 * the same SONAME (build.py links it with -soname LOADER_SONAME), so dlopen(LOADER_SONAME, RTLD_NOLOAD)
 * finds the copy loaded first in the process, whichever FMU it belongs to, and every copy uses that
 * copy's `emcosim_fmu_process_v1`. The dynamic linker serializes dlopen and keeps its list of loaded
 * objects in load order, so all copies agree on the first one; the handle taken from another copy keeps
 * that copy loaded. A copy of an older build (without the SONAME) keeps its own lock. */
#ifndef LOADER_SONAME
#error "LOADER_SONAME must be defined (build.py passes -DLOADER_SONAME and links with the same -soname)"
#endif
typedef struct {                             /* version 1: a lock and a flag; never change its layout */
    pthread_mutex_t lock;                    /* held while Python is started and pythonfmu's library loaded */
    int python_started;                      /* an emcosim loader started the process's Python */
} ProcessState;

__attribute__((visibility("default"))) ProcessState emcosim_fmu_process_v1 = {PTHREAD_MUTEX_INITIALIZER, 0};

/* ---- state of this library (one per FMU: every FMU ships its own copy) ------------------------------ */
static pthread_mutex_t process_lookup_lock = PTHREAD_MUTEX_INITIALIZER;
static ProcessState *process;                /* the process's (`emcosim_fmu_process_v1` of the first copy) */
static int setup_done;                       /* Python and pythonfmu's library are ready */
static char setup_error[MESSAGE_SIZE];       /* or why not (then every fmi2Instantiate reports it) */

typedef struct {                             /* the value references of the last call, as a Python list */
    fmi2ValueReference *vr;
    size_t n;
    PyObject *list;
} VrCache;

typedef struct {
    fmi2Component inner;                     /* pythonfmu's instance */
    char *name;
    char package[128];                       /* the bundle package (fmus.pythonfmu_workarounds is found there) */
    fmi2Type type;                           /* the host's fmuType */
    fmi2CallbackFunctions host;              /* the host's callbacks, copied */
    fmi2CallbackFunctions callbacks;         /* given to pythonfmu: its messages go through `relay` */
    int logging_on;                          /* the host's loggingOn (fmi2Instantiate, fmi2SetDebugLogging) */
    int failed;                              /* fmi2Reset failed: only fmi2FreeInstance is left */
    int busy;                                /* calls of this instance in progress (a logger may call back) */
    PyObject *slave;                         /* the EMSlave (a strong reference), or NULL: forward all */
    PyObject *log_queue;                     /* slave.log_queue, drained after every call */
    PyObject *set_real, *get_real, *do_step; /* the slave's methods of every communication step */
    PyObject *set_time, *set_states, *get_derivatives;   /* ... and of every right-hand side (Model Exchange), */
    PyObject *get_states, *get_indicators;    /* and of every step of a host's solver */
    VrCache set_vrs, get_vrs;
    size_t nx, ni;                           /* the FMU's continuous states and event indicators (fmi2_get_sizes) */
    size_t n_reals, n_integers;              /* its Real and Integer variables */
    size_t max_output_order;                 /* its maxOutputDerivativeOrder */
    PyObject **states;                       /* the FMU states this instance gave out (strong references) */
    size_t n_states, cap_states;
} Instance;

typedef struct {
    char executable[PATH_MAX];               /* the Python interpreter (sys.executable) */
    char library[PATH_MAX];                  /* its libpython */
    char version[32];                        /* its version, "3.11.7" */
    char minor[16];                          /* "3.11": any 3.11.x can replace it */
    char package[128];                       /* the FMU's bundle package, emcosim_fmu_<tag> */
    char script[160];                        /* the script pythonfmu runs, emcosim_fmu_<tag>_<id> */
    char build[80];                          /* the build fingerprint (the package's BUILD) */
    char multiarch[64];                      /* lib/<multiarch> of a Debian-style libpython */
    char guid[64];                           /* the modelDescription's guid */
} Record;

/* ---- logging through the host's callback ------------------------------------------------------------ */
static const char *category_of(fmi2Status status)
{
    static const char *names[] = {"logStatusOK", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                  "logStatusFatal", "logStatusPending"};
    return status <= fmi2Pending ? names[status] : "logAll";
}

/* The logger's message is a printf format (FMI 2.0): '%' is doubled; hosts that do not format it (fmpy)
 * show it as it is. Without a logger: stderr. */
static void log_text(const fmi2CallbackFunctions *callbacks, const char *instance, fmi2Status status,
                     const char *category, const char *text)
{
    char escaped[2 * MESSAGE_SIZE];
    size_t n = 0;
    for (const char *p = text; *p && n + 2 < sizeof escaped; p++) {
        if (*p == '%') escaped[n++] = '%';
        escaped[n++] = *p;
    }
    escaped[n] = '\0';
    if (callbacks != NULL && callbacks->logger != NULL)
        callbacks->logger(callbacks->componentEnvironment, instance ? instance : "", status,
                          category && category[0] ? category : category_of(status), escaped);
    else
        fprintf(stderr, "[%s] %s\n", instance ? instance : "", text);
}

static void log_to_host(const fmi2CallbackFunctions *callbacks, const char *instance, fmi2Status status,
                        const char *format, ...)
{
    char message[MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    log_text(callbacks, instance, status, NULL, message);
}

/* A message of an instance: warnings and worse always, the rest only with loggingOn. */
static void emit(Instance *instance, fmi2Status status, const char *category, const char *text)
{
    if (status >= fmi2Warning || instance->logging_on)
        log_text(&instance->host, instance->name, status, category, text);
}

static void emitf(Instance *instance, fmi2Status status, const char *format, ...)
{
    char message[MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    emit(instance, status, NULL, message);
}

/* pythonfmu's logger callback: its messages are plain text (no format arguments). */
static void relay(fmi2ComponentEnvironment environment, fmi2String name, fmi2Status status, fmi2String category,
                  fmi2String message, ...)
{
    (void)name;
    emit((Instance *)environment, status, category, message ? message : "");
}

/* ---- the record of build.py ------------------------------------------------------------------------ */
static void copy_string(char *dest, size_t size, const char *src)
{
    snprintf(dest, size, "%s", src);
}

static int read_record(const char *resources, Record *record, char *error)
{
    char path[PATH_MAX + 32], line[PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/%s", resources, RECORD_FILE);
    FILE *f = fopen(path, "r");
    if (f == NULL) {
        snprintf(error, MESSAGE_SIZE, "cannot read %s (%s): the FMU is incomplete", path, strerror(errno));
        return -1;
    }
    memset(record, 0, sizeof *record);
    while (fgets(line, sizeof line, f) != NULL) {
        char *eq = strchr(line, '=');
        if (line[0] == '#' || eq == NULL) continue;
        *eq = '\0';
        char *key = line, *value = eq + 1;
        while (*key == ' ') key++;
        for (char *end = eq - 1; end >= key && *end == ' '; end--) *end = '\0';
        while (*value == ' ') value++;
        value[strcspn(value, "\r\n")] = '\0';
        if (strcmp(key, "python_executable") == 0) copy_string(record->executable, sizeof record->executable, value);
        else if (strcmp(key, "python_library") == 0) copy_string(record->library, sizeof record->library, value);
        else if (strcmp(key, "python_version") == 0) copy_string(record->version, sizeof record->version, value);
        else if (strcmp(key, "package") == 0) copy_string(record->package, sizeof record->package, value);
        else if (strcmp(key, "script") == 0) copy_string(record->script, sizeof record->script, value);
        else if (strcmp(key, "build") == 0) copy_string(record->build, sizeof record->build, value);
        else if (strcmp(key, "multiarch") == 0) copy_string(record->multiarch, sizeof record->multiarch, value);
        else if (strcmp(key, "guid") == 0) copy_string(record->guid, sizeof record->guid, value);
    }
    fclose(f);
    int major = 0, minor = 0;
    sscanf(record->version, "%d.%d", &major, &minor);
    snprintf(record->minor, sizeof record->minor, "%d.%d", major, minor);
    if (!record->executable[0] || !record->library[0] || !record->package[0] || !record->script[0] ||
        !record->build[0]) {
        snprintf(error, MESSAGE_SIZE, "%s lacks python_executable, python_library, package, script or build", path);
        return -1;
    }
    return 0;
}

/* The local path of a file: URI (file:///p, file://localhost/p, file:/p), %XX decoded. */
static int uri_to_path(const char *uri, char *path, size_t size)
{
    const char *p = uri;
    if (strncmp(p, "file://localhost/", 17) == 0) p += 16;
    else if (strncmp(p, "file:///", 8) == 0) p += 7;
    else if (strncmp(p, "file:/", 6) == 0) p += 5;
    else if (p[0] != '/') return -1;
    size_t n = 0;
    for (; *p && n + 1 < size; p++) {
        unsigned hex;
        if (p[0] == '%' && p[1] && p[2] && sscanf(p + 1, "%2x", &hex) == 1) {
            path[n++] = (char)hex;
            p += 2;
        } else {
            path[n++] = *p;
        }
    }
    path[n] = '\0';
    while (n > 1 && path[n - 1] == '/') path[--n] = '\0';
    return *p ? -1 : 0;
}

/* ---- Python ------------------------------------------------------------------------------------------ */
static int same_minor_version(const char *a, const char *b)
{
    int a1 = 0, a2 = 0, b1 = 0, b2 = 0;
    return sscanf(a, "%d.%d", &a1, &a2) == 2 && sscanf(b, "%d.%d", &b1, &b2) == 2 && a1 == b1 && a2 == b2;
}

/* libpython of the interpreter `executable` (EMCOSIM_FMU_PYTHON): <prefix>/lib[/<multiarch>]/libpythonX.Y.so.1.0,
 * where <prefix>/bin holds the interpreter after symbolic links, or is the `home` of a venv's pyvenv.cfg. */
static int find_libpython(const char *executable, const Record *record, char *library, size_t size)
{
    char real[PATH_MAX], bin[PATH_MAX * 2], line[PATH_MAX + 16];
    char name[64];
    snprintf(name, sizeof name, "libpython%s.so.1.0", record->minor);
    const char *bins[2] = {NULL, NULL};
    if (realpath(executable, real) != NULL) {
        char *slash = strrchr(real, '/');
        if (slash) *slash = '\0';
        bins[0] = real;
    }
    copy_string(bin, sizeof bin, executable);                       /* a venv copied with --copies */
    char *slash = strrchr(bin, '/');
    if (slash) {
        strcpy(slash, "/../pyvenv.cfg");
        FILE *f = fopen(bin, "r");
        bin[0] = '\0';
        while (f != NULL && fgets(line, sizeof line, f) != NULL) {
            char *value = line + 4;
            if (strncmp(line, "home", 4) != 0) continue;
            while (*value == ' ' || *value == '=') value++;
            value[strcspn(value, "\r\n")] = '\0';
            copy_string(bin, sizeof bin, value);
        }
        if (f) fclose(f);
        if (bin[0]) bins[1] = bin;
    }
    for (int i = 0; i < 2; i++) {
        if (bins[i] == NULL) continue;
        const char *subdirs[] = {"lib", "lib64", NULL};
        char candidate[PATH_MAX * 3];
        for (int j = 0; subdirs[j]; j++) {
            snprintf(candidate, sizeof candidate, "%s/../%s/%s", bins[i], subdirs[j], name);
            if (access(candidate, R_OK) == 0 && realpath(candidate, library) != NULL) return 0;
            if (record->multiarch[0]) {
                snprintf(candidate, sizeof candidate, "%s/../%s/%s/%s", bins[i], subdirs[j], record->multiarch, name);
                if (access(candidate, R_OK) == 0 && realpath(candidate, library) != NULL) return 0;
            }
        }
    }
    (void)size;
    return -1;
}

static void python_error_text(char *text, size_t size)
{
    PyObject *type = NULL, *value = NULL, *traceback = NULL;
    py.PyErr_Fetch(&type, &value, &traceback);
    PyObject *name = type ? py.PyObject_GetAttrString(type, "__name__") : NULL;
    PyObject *str = value ? py.PyObject_Str(value) : NULL;
    const char *n = name ? py.PyUnicode_AsUTF8(name) : NULL, *s = str ? py.PyUnicode_AsUTF8(str) : NULL;
    snprintf(text, size, "%s: %s", n ? n : "error", s ? s : "(no message)");
    PyObject *objects[] = {name, str, type, value, traceback};
    for (int i = 0; i < 5; i++)
        if (objects[i]) py.Py_DecRef(objects[i]);
    if (py.PyErr_Occurred()) {                                       /* from the formatting itself */
        py.PyErr_Fetch(&type, &value, &traceback);
        if (type) py.Py_DecRef(type);
        if (value) py.Py_DecRef(value);
        if (traceback) py.Py_DecRef(traceback);
    }
}

/* Start Python in this process (none is running): the recorded interpreter, or EMCOSIM_FMU_PYTHON's. */
static int start_python(const Record *record, char *error)
{
    const char *override = getenv(OVERRIDE_VARIABLE);
    const char *executable = override && override[0] ? override : record->executable;
    const char *source = override && override[0] ? "set by " OVERRIDE_VARIABLE : "recorded by build.py in resources/" RECORD_FILE;
    char library[PATH_MAX];
    const char *hint = "set " OVERRIDE_VARIABLE " to a Python %s executable whose environment has numpy and scipy";
    char want[160];
    snprintf(want, sizeof want, hint, record->minor);

    if (access(executable, X_OK) != 0) {
        snprintf(error, MESSAGE_SIZE, "this FMU needs Python %s with numpy and scipy: the interpreter %s (%s) "
                 "does not exist or is not executable; %s", record->minor, executable, source, want);
        return -1;
    }
    void *handle = dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    if (handle != NULL) {                                     /* the host links a libpython it has not started */
        handle = RTLD_DEFAULT;
    } else {
        if (override && override[0]) {
            if (find_libpython(executable, record, library, sizeof library) != 0) {
                snprintf(error, MESSAGE_SIZE, "this FMU needs Python %s with numpy and scipy: no shared library "
                         "libpython%s.so.1.0 found for the interpreter %s (%s) in lib/ beside its bin/ folder; %s",
                         record->minor, record->minor, executable, source, want);
                return -1;
            }
        } else {
            copy_string(library, sizeof library, record->library);
        }
        handle = dlopen(library, RTLD_NOW | RTLD_GLOBAL);
        if (handle == NULL) {
            snprintf(error, MESSAGE_SIZE, "this FMU needs Python %s with numpy and scipy: cannot load its library "
                     "(%s); %s", record->minor, dlerror(), want);
            return -1;
        }
    }
    const char *missing = bind_python(handle);
    if (missing != NULL) {
        snprintf(error, MESSAGE_SIZE, "the Python library of %s lacks %s; %s", executable, missing, want);
        return -1;
    }
    const char *version = py.Py_GetVersion();
    if (!same_minor_version(version, PY_VERSION) || !same_minor_version(record->version, PY_VERSION)) {
        snprintf(error, MESSAGE_SIZE, "this FMU needs Python %d.%d: %s is Python %.12s; %s", PY_MAJOR_VERSION,
                 PY_MINOR_VERSION, executable, version, want);
        return -1;
    }
    if (py.Py_IsInitialized()) return 0;

    PyConfig config;
    py.PyConfig_InitIsolatedConfig(&config);          /* ignores PYTHON* variables; installs no signal handler */
    config.user_site_directory = 1;                   /* the interpreter's environment, as `python` sees it */
    config.buffered_stdio = 0;                        /* never finalized: nothing may wait in a buffer */
    PyStatus status = py.PyConfig_SetBytesString(&config, &config.executable, executable);
    if (!py.PyStatus_Exception(status)) status = py.PyConfig_SetBytesString(&config, &config.program_name, executable);
    if (!py.PyStatus_Exception(status)) status = py.Py_InitializeFromConfig(&config);
    py.PyConfig_Clear(&config);
    if (py.PyStatus_Exception(status)) {
        snprintf(error, MESSAGE_SIZE, "Python %s (%s) did not start: %s; %s", executable, source,
                 status.err_msg ? status.err_msg : "unknown error", want);
        return -1;
    }
    py.PyEval_SaveThread();                           /* release the GIL: every call below takes it */
    return 0;
}

/* A module of this FMU's names (its bundle package, its script) already loaded in the process must be this
 * build's (its BUILD equals the record's): else the FMU would run another build's code, or a foreign module
 * named like ours. 0 if not loaded or ours; else -1 with the reason. GIL held. */
static int check_module_build(const char *name, const char *build, char *error)
{
    char text[MESSAGE_SIZE];
    PyObject *key = py.PyUnicode_FromString(name);
    PyObject *module = key ? py.PyImport_GetModule(key) : NULL;
    if (key) py.Py_DecRef(key);
    if (module == NULL) {
        if (!py.PyErr_Occurred()) return 0;
        python_error_text(text, sizeof text);
        snprintf(error, MESSAGE_SIZE, "cannot look up module %s in sys.modules: %s", name, text);
        return -1;
    }
    PyObject *loaded = py.PyObject_GetAttrString(module, "BUILD");
    PyObject *file = loaded ? py.PyObject_GetAttrString(module, "__file__") : NULL;
    if (py.PyErr_Occurred()) python_error_text(text, sizeof text);
    const char *value = loaded ? py.PyUnicode_AsUTF8(loaded) : NULL, *where = file ? py.PyUnicode_AsUTF8(file) : NULL;
    int ours = value != NULL && strcmp(value, build) == 0;
    if (!ours)
        snprintf(error, MESSAGE_SIZE, "module %s is already loaded in this process (from %s) and is not this FMU's "
                 "(build %s, found %s): another FMU with a module of this name was instantiated first; FMUs sharing "
                 "a process must not share module names unless they come from one build", name,
                 where ? where : "?", build, value ? value : "no BUILD");
    if (py.PyErr_Occurred()) python_error_text(text, sizeof text);
    if (loaded) py.Py_DecRef(loaded);
    if (file) py.Py_DecRef(file);
    py.Py_DecRef(module);
    return ours ? 0 : -1;
}

/* If the bundle package is loaded already (another FMU of this build), let it also find modules in this
 * FMU's copy (package.add_folder, written by build.py): the first FMU's folder may be gone. GIL held. */
static int add_folder(const char *package, const char *resources)
{
    char folder[PATH_MAX + 160];
    snprintf(folder, sizeof folder, "%s/%s", resources, package);
    PyObject *key = py.PyUnicode_FromString(package);
    PyObject *module = key ? py.PyImport_GetModule(key) : NULL;
    PyObject *add = module ? py.PyObject_GetAttrString(module, "add_folder") : NULL;
    PyObject *argument = add ? py.PyUnicode_FromString(folder) : NULL;
    PyObject *result = argument ? py.PyObject_CallFunctionObjArgs(add, argument, NULL) : NULL;
    int failed = py.PyErr_Occurred() != NULL || (module != NULL && result == NULL);
    PyObject *objects[] = {key, module, add, argument, result};
    for (int i = 0; i < 5; i++)
        if (objects[i]) py.Py_DecRef(objects[i]);
    return failed ? -1 : 0;
}

/* numpy and scipy import, and no module of this FMU's names is another build's. */
static int check_environment(const Record *record, const char *resources, int started, char *error)
{
    char text[MESSAGE_SIZE];
    int failed = 0;
    PyGILState_STATE gil = py.PyGILState_Ensure();
    const char *needed[] = {"numpy", "scipy"};
    for (int i = 0; i < 2 && !failed; i++) {
        PyObject *m = py.PyImport_ImportModule(needed[i]);
        if (m == NULL) {
            python_error_text(text, sizeof text);
            const char *override = getenv(OVERRIDE_VARIABLE);
            if (started)
                snprintf(error, MESSAGE_SIZE, "the Python %s cannot import %s (%s); set " OVERRIDE_VARIABLE " to a "
                         "Python %s executable whose environment has numpy and scipy, and restart the host",
                         override && override[0] ? override : record->executable, needed[i], text, record->minor);
            else
                snprintf(error, MESSAGE_SIZE, "the host's Python cannot import %s (%s): install numpy and scipy "
                         "in the environment of the host process", needed[i], text);
            failed = 1;
        } else {
            py.Py_DecRef(m);
        }
    }
    const char *names[] = {record->package, record->script};
    for (int i = 0; i < 2 && !failed; i++) {
        failed = check_module_build(names[i], record->build, error);
    }
    if (!failed && add_folder(record->package, resources) != 0) {
        python_error_text(text, sizeof text);
        snprintf(error, MESSAGE_SIZE, "%s.add_folder failed: %s", record->package, text);
        failed = 1;
    }
    py.PyGILState_Release(gil);
    return failed ? -1 : 0;
}

/* pythonfmu's library, beside this one. */
static int load_pythonfmu(char *error)
{
    Dl_info info;
    char path[PATH_MAX + 64];
    if (dladdr((void *)&load_pythonfmu, &info) == 0 || info.dli_fname == NULL) {
        snprintf(error, MESSAGE_SIZE, "cannot find the path of the FMU's binary (dladdr)");
        return -1;
    }
    copy_string(path, sizeof path, info.dli_fname);
    char *slash = strrchr(path, '/');
    snprintf(slash ? slash + 1 : path, sizeof path - (slash ? (size_t)(slash + 1 - path) : 0), "%s", PYTHONFMU_LIBRARY);
    void *handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (handle == NULL) {
        snprintf(error, MESSAGE_SIZE, "cannot load pythonfmu's library: %s", dlerror());
        return -1;
    }
#define BIND(name)                                                                                        \
    if ((lib.name = (name##TYPE *)dlsym(handle, #name)) == NULL) {                                        \
        snprintf(error, MESSAGE_SIZE, "%s lacks %s", path, #name);                                        \
        return -1;                                                                                        \
    }
    FORWARDED(BIND)
#undef BIND
    /* pythonfmu 0.7.0 keeps its interpreter state in a global shared_ptr that both its C++ static destructor
     * and its ELF destructor reset at exit, the second after the first has freed it: the heap was corrupted
     * at the exit of about 1 process in 3 (docs/reliability.md, finding 1; measured again with a plain
     * pythonfmu slave behind this loader: "free(): corrupted unsorted chunks" at every exit). An exit
     * handler registered now, after the library's own, runs first and releases the state while it is
     * intact; the destructors then find it empty. The library is never unloaded (glibc marks it NODELETE:
     * it defines unique symbols), so the handler stays valid even if the host unloads this library. */
    lib.finalizePythonInterpreter = (void (*)(void))dlsym(handle, "finalizePythonInterpreter");
    if (lib.finalizePythonInterpreter == NULL ||
        __cxa_atexit((void (*)(void *))(void (*)(void))lib.finalizePythonInterpreter, NULL, NULL) != 0) {
        snprintf(error, MESSAGE_SIZE, "cannot register pythonfmu's exit handler (finalizePythonInterpreter)");
        return -1;
    }
    return 0;
}

/* The process's state: `emcosim_fmu_process_v1` of the copy of this library loaded first (see above). */
static ProcessState *process_state(void)
{
    pthread_mutex_lock(&process_lookup_lock);
    if (process == NULL) {
        void *first = dlopen(LOADER_SONAME, RTLD_NOW | RTLD_NOLOAD);
        ProcessState *found = first ? (ProcessState *)dlsym(first, "emcosim_fmu_process_v1") : NULL;
        process = found ? found : &emcosim_fmu_process_v1;
        if (first && process == &emcosim_fmu_process_v1) dlclose(first);   /* this copy: no extra reference */
    }
    pthread_mutex_unlock(&process_lookup_lock);
    return process;
}

/* Python running, the environment checked, pythonfmu loaded: once per process and FMU binary, except the
 * checks (per instance: another FMU may have loaded something in between). Python is started under the
 * process's lock, which every emcosim FMU of the process shares. */
static int set_up(const Record *record, const char *resources, char *error)
{
    ProcessState *shared = process_state();
    pthread_mutex_lock(&shared->lock);
    if (!setup_done && !setup_error[0]) {
        int (*is_initialized)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
        if (is_initialized != NULL && is_initialized()) {                 /* the host's Python (fmpy, ...) */
            const char *missing = bind_python(RTLD_DEFAULT);            /* or another emcosim FMU's */
            if (missing) snprintf(setup_error, sizeof setup_error, "the host's Python lacks %s", missing);
        } else if (start_python(record, setup_error) == 0) {
            shared->python_started = 1;
        }
        if (!setup_error[0]) load_pythonfmu(setup_error);
        setup_done = !setup_error[0];
    }
    int started = shared->python_started;
    pthread_mutex_unlock(&shared->lock);
    if (!setup_done) {
        copy_string(error, MESSAGE_SIZE, setup_error);
        return -1;
    }
    return check_environment(record, resources, started, error);
}

/* ---- the registry of live instances (per FMU binary) -------------------------------------------------- */
static pthread_mutex_t registry_lock = PTHREAD_MUTEX_INITIALIZER;
static Instance **live;
static size_t n_live, cap_live;

static int grow(void **array, size_t *capacity, size_t needed, size_t item)
{
    if (needed <= *capacity) return 0;
    size_t capacity2 = *capacity ? 2 * *capacity : 8;
    void *array2 = realloc(*array, capacity2 * item);
    if (array2 == NULL) return -1;
    *array = array2;
    *capacity = capacity2;
    return 0;
}

static int register_instance(Instance *instance)
{
    pthread_mutex_lock(&registry_lock);
    int failed = grow((void **)&live, &cap_live, n_live + 1, sizeof *live);
    if (!failed) live[n_live++] = instance;
    pthread_mutex_unlock(&registry_lock);
    return failed ? -1 : 0;
}

static void unregister_instance(Instance *instance)
{
    pthread_mutex_lock(&registry_lock);
    for (size_t i = 0; i < n_live; i++)
        if (live[i] == instance) {
            live[i] = live[--n_live];
            break;
        }
    pthread_mutex_unlock(&registry_lock);
}

/* The live instance `c`, or NULL (a NULL, unknown or freed instance: said on stderr, the host's logger is
 * not known). An instance whose fmi2Reset failed answers fmi2Error to everything but fmi2FreeInstance. */
static Instance *lookup(fmi2Component c, const char *function)
{
    Instance *found = NULL;
    pthread_mutex_lock(&registry_lock);
    for (size_t i = 0; i < n_live && found == NULL; i++)
        if (live[i] == (Instance *)c) found = live[i];
    pthread_mutex_unlock(&registry_lock);
    if (found == NULL)
        fprintf(stderr, "emcosim FMU: %s called with %s instance (%p); refused\n", function,
                c == NULL ? "a NULL" : "an unknown or freed", c);
    else if (found->failed && strcmp(function, "fmi2FreeInstance") != 0) {
        emitf(found, fmi2Error, "%s: this instance failed in fmi2Reset; only fmi2FreeInstance is possible", function);
        return NULL;
    }
    return found;
}

/* Is `state` one the instances of this FMU gave out (and did not free)? Its owner, or NULL. */
static Instance *owner_of(fmi2FMUstate state, size_t *index)
{
    Instance *owner = NULL;
    pthread_mutex_lock(&registry_lock);
    for (size_t i = 0; i < n_live && owner == NULL; i++)
        for (size_t j = 0; j < live[i]->n_states; j++)
            if (live[i]->states[j] == (PyObject *)state) {
                owner = live[i];
                *index = j;
                break;
            }
    pthread_mutex_unlock(&registry_lock);
    return owner;
}

static int add_state(Instance *instance, PyObject *state)
{
    pthread_mutex_lock(&registry_lock);
    int failed = grow((void **)&instance->states, &instance->cap_states, instance->n_states + 1,
                      sizeof *instance->states);
    if (!failed) instance->states[instance->n_states++] = state;
    pthread_mutex_unlock(&registry_lock);
    return failed ? -1 : 0;
}

static void remove_state(Instance *owner, size_t index)
{
    pthread_mutex_lock(&registry_lock);
    owner->states[index] = owner->states[--owner->n_states];
    pthread_mutex_unlock(&registry_lock);
}

/* ---- the Python slave of an instance ------------------------------------------------------------------ */
static void clear(PyObject **object)
{
    if (*object != NULL) py.Py_DecRef(*object);
    *object = NULL;
}

static void clear_vrs(VrCache *cache)
{
    clear(&cache->list);
    free(cache->vr);
    cache->vr = NULL;
    cache->n = 0;
}

/* The slave's references the loader holds: the slave, its log queue and the bound methods of the hot calls. */
#define SLAVE_OBJECTS(instance)                                                                           \
    {&(instance)->slave, &(instance)->log_queue, &(instance)->set_real, &(instance)->get_real,               \
     &(instance)->do_step, &(instance)->set_time, &(instance)->set_states, &(instance)->get_derivatives,        \
     &(instance)->get_states, &(instance)->get_indicators}
#define N_SLAVE_OBJECTS 10

/* The EMSlave pythonfmu constructed last on this thread (fmus.pythonfmu_workarounds.take_new_slave), with
 * the methods of every communication step and right-hand side, and its log queue; none for a slave that is
 * not an EMSlave (then every call goes to pythonfmu's library). GIL held. */
static void take_slave(Instance *instance)
{
    char module[256], text[MESSAGE_SIZE];
    PyObject **objects[] = SLAVE_OBJECTS(instance);
    for (int i = 0; i < N_SLAVE_OBJECTS; i++) clear(objects[i]);
    clear_vrs(&instance->set_vrs);
    clear_vrs(&instance->get_vrs);
    snprintf(module, sizeof module, "%s.fmus.pythonfmu_workarounds", instance->package);
    PyObject *workarounds = py.PyImport_ImportModule(module);
    PyObject *take = workarounds ? py.PyObject_GetAttrString(workarounds, "take_new_slave") : NULL;
    PyObject *slave = take ? py.PyObject_CallFunctionObjArgs(take, NULL) : NULL;
    if (workarounds) py.Py_DecRef(workarounds);
    if (take) py.Py_DecRef(take);
    if (slave == NULL) {                      /* a bundle without the framework: pythonfmu answers */
        python_error_text(text, sizeof text);
        emitf(instance, fmi2Warning, "%s.take_new_slave failed (%s): pythonfmu answers every call", module, text);
        return;
    }
    instance->slave = slave;                  /* None: a slave that is not an EMSlave */
    instance->do_step = py.PyObject_GetAttrString(slave, "fmi2_do_step");
    instance->log_queue = py.PyObject_GetAttrString(slave, "log_queue");
    instance->set_real = py.PyObject_GetAttrString(slave, "fmi2_set_real");
    instance->get_real = py.PyObject_GetAttrString(slave, "fmi2_get_real");
    instance->set_time = py.PyObject_GetAttrString(slave, "fmi2_set_time");
    instance->set_states = py.PyObject_GetAttrString(slave, "fmi2_set_continuous_states");
    instance->get_derivatives = py.PyObject_GetAttrString(slave, "fmi2_get_derivatives");
    instance->get_states = py.PyObject_GetAttrString(slave, "fmi2_get_continuous_states");
    instance->get_indicators = py.PyObject_GetAttrString(slave, "fmi2_get_event_indicators");
    int complete = 1;
    for (int i = 0; i < N_SLAVE_OBJECTS; i++) complete = complete && *objects[i] != NULL;
    if (!complete)
        for (int i = 0; i < N_SLAVE_OBJECTS; i++) clear(objects[i]);
    py.PyErr_Clear();
}

/* Forward the slave's log messages (LogMsg: status, category, msg) to the host and empty the queue; how
 * many there were. The queue is emptied before the first message goes out: a host's logger may call back
 * into the instance, and that call drains the queue again (issue 26, item 7: reading the queue by index
 * while the call-back emptied it crashed the host). GIL held. */
static Py_ssize_t drain(Instance *instance)
{
    Py_ssize_t n = instance->log_queue ? py.PyList_Size(instance->log_queue) : 0;
    PyObject *batch = n > 0 ? py.PyList_GetSlice(instance->log_queue, 0, n) : NULL;
    if (batch == NULL) {
        py.PyErr_Clear();
        return 0;
    }
    py.PyList_SetSlice(instance->log_queue, 0, n, NULL);
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *entry = py.PyList_GetItem(batch, i);
        PyObject *status = py.PyObject_GetAttrString(entry, "status");
        PyObject *category = py.PyObject_GetAttrString(entry, "category");
        PyObject *text = py.PyObject_GetAttrString(entry, "msg");
        long code = status ? py.PyLong_AsLong(status) : fmi2Error;
        const char *c = category ? py.PyUnicode_AsUTF8(category) : NULL;
        const char *t = text ? py.PyUnicode_AsUTF8(text) : NULL;
        py.PyErr_Clear();                                   /* a category None: no string */
        emit(instance, code >= fmi2OK && code <= fmi2Fatal ? (fmi2Status)code : fmi2Error, c, t ? t : "(no message)");
        PyObject *objects[] = {status, category, text};
        for (int k = 0; k < 3; k++)
            if (objects[k]) py.Py_DecRef(objects[k]);
    }
    py.Py_DecRef(batch);
    py.PyErr_Clear();
    return n;
}

typedef struct {
    fmi2Status status;
    PyObject *value;                          /* the middle item of a 3-tuple answer (new reference), or NULL */
} Answer;

/* Call the slave's method (`bound`, else looked up by `method`) with the arguments (up to 5, consumed;
 * NULL from a failed allocation fails the call). It answers (status, message) or, with `items` = 3,
 * (status, value, message). The message is logged with the status, then what the slave logged during
 * the call (the details, last: hosts that keep one message keep those), else a generic one for a failure.
 * GIL held. */
static Answer ask(Instance *instance, const char *function, PyObject *bound, const char *method,
                  PyObject *args[], int nargs, int items)
{
    char text[MESSAGE_SIZE];
    Answer answer = {fmi2Error, NULL};
    PyObject *a[5] = {NULL, NULL, NULL, NULL, NULL};
    int complete = 1;
    for (int i = 0; i < nargs; i++) {
        a[i] = args[i];
        complete = complete && args[i] != NULL;
    }
    instance->busy++;                         /* fmi2FreeInstance and fmi2Reset wait until it returns */
    PyObject *callable = bound;
    if (callable != NULL) py.Py_IncRef(callable);
    else callable = py.PyObject_GetAttrString(instance->slave, method);
    PyObject *result = callable && complete ? py.PyObject_CallFunctionObjArgs(callable, a[0], a[1], a[2], a[3], a[4], NULL) : NULL;
    const char *message = NULL;
    if (result != NULL && py.PyTuple_Size(result) == items) {
        long code = py.PyLong_AsLong(py.PyTuple_GetItem(result, 0));
        answer.status = code >= fmi2OK && code <= fmi2Fatal ? (fmi2Status)code : fmi2Error;
        message = py.PyUnicode_AsUTF8(py.PyTuple_GetItem(result, items - 1));
        if (items == 3) {
            answer.value = py.PyTuple_GetItem(result, 1);
            py.Py_IncRef(answer.value);
        }
    }
    if (message == NULL) {
        if (py.PyErr_Occurred()) python_error_text(text, sizeof text);
        else snprintf(text, sizeof text, "%s did not answer (status, %smessage)", method ? method : function,
                      items == 3 ? "value, " : "");
        answer.status = fmi2Error;
        clear(&answer.value);
    }
    if (message == NULL) emitf(instance, fmi2Error, "%s: %s", function, text);
    else if (message[0]) emit(instance, answer.status, NULL, message);
    if (drain(instance) == 0 && message != NULL && !message[0] && answer.status > fmi2Warning)
        emitf(instance, answer.status, "%s failed", function);
    if (callable) py.Py_DecRef(callable);
    if (result) py.Py_DecRef(result);
    for (int i = 0; i < nargs; i++)
        if (args[i]) py.Py_DecRef(args[i]);
    instance->busy--;
    return answer;
}

static PyObject *list_of_vrs(const fmi2ValueReference *vr, size_t n)
{
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) py.PyList_SetItem(list, (Py_ssize_t)i, py.PyLong_FromUnsignedLong(vr[i]));
    return list;
}

/* The same list again while the host passes the same value references (every step, usually). */
static PyObject *cached_vrs(VrCache *cache, const fmi2ValueReference *vr, size_t n)
{
    if (cache->list == NULL || cache->n != n || (n > 0 && memcmp(cache->vr, vr, n * sizeof *vr) != 0)) {
        clear_vrs(cache);
        if ((cache->vr = malloc((n ? n : 1) * sizeof *vr)) == NULL) return NULL;
        memcpy(cache->vr, vr, n * sizeof *vr);
        cache->n = n;
        cache->list = list_of_vrs(vr, n);
    }
    if (cache->list) py.Py_IncRef(cache->list);
    return cache->list;
}

static PyObject *list_of_ints(const fmi2Integer *v, size_t n)
{
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) py.PyList_SetItem(list, (Py_ssize_t)i, py.PyLong_FromLong(v[i]));
    return list;
}

static PyObject *list_of_reals(const fmi2Real *v, size_t n)
{
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) py.PyList_SetItem(list, (Py_ssize_t)i, py.PyFloat_FromDouble(v[i]));
    return list;
}

/* Copy a list answer of n values (also with an error status: the values are defined, e.g. NaN). */
static fmi2Status copy_values(Instance *instance, const char *function, Answer answer, fmi2Real *reals,
                              fmi2Integer *ints, size_t n)
{
    if (answer.value != NULL && py.PyList_Size(answer.value) == (Py_ssize_t)n) {
        for (size_t i = 0; i < n; i++) {
            PyObject *item = py.PyList_GetItem(answer.value, (Py_ssize_t)i);
            if (reals) reals[i] = py.PyFloat_AsDouble(item);
            else ints[i] = (fmi2Integer)py.PyLong_AsLong(item);
        }
    } else if (answer.status <= fmi2Warning) {
        emitf(instance, fmi2Error, "%s: the slave answered a wrong number of values", function);
        answer.status = fmi2Error;
    }
    py.PyErr_Clear();
    clear(&answer.value);
    return answer.status;
}

/* The slave's numbers every count is checked against (slave.fmi2_get_sizes: nx, ni, Real and Integer
 * variables). GIL held. */
static fmi2Status take_sizes(Instance *instance)
{
    Answer answer = ask(instance, "fmi2Instantiate", NULL, "fmi2_get_sizes", NULL, 0, 3);
    long sizes[5] = {-1, -1, -1, -1, -1};
    for (int i = 0; answer.status <= fmi2Warning && answer.value != NULL && i < 5; i++)
        sizes[i] = py.PyLong_AsLong(py.PyTuple_GetItem(answer.value, i));
    py.PyErr_Clear();
    clear(&answer.value);
    if (answer.status > fmi2Warning) return answer.status;
    for (int i = 0; i < 5; i++)
        if (sizes[i] < 0) {
            emitf(instance, fmi2Error, "fmi2Instantiate: the slave's fmi2_get_sizes did not answer five counts");
            return fmi2Error;
        }
    instance->nx = (size_t)sizes[0];
    instance->ni = (size_t)sizes[1];
    instance->n_reals = (size_t)sizes[2];
    instance->n_integers = (size_t)sizes[3];
    instance->max_output_order = (size_t)sizes[4];
    return fmi2OK;
}

/* Take the new slave, its sizes, and tell it the host's fmuType (slave.fmi2_set_interface). A slave that is
 * not an emcosim one can only be a Co-Simulation instance (pythonfmu answers). GIL held. */
static fmi2Status tell_interface(Instance *instance)
{
    take_slave(instance);
    if (instance->slave == NULL) {
        if (instance->type == fmi2CoSimulation) return fmi2OK;
        emitf(instance, fmi2Error, "fmi2Instantiate: this FMU's slave is not an emcosim one: Co-Simulation only");
        return fmi2Error;
    }
    fmi2Status sized = take_sizes(instance);
    if (sized > fmi2Warning) return sized;
    PyObject *args[1] = {py.PyLong_FromLong((long)instance->type)};
    return ask(instance, "fmi2Instantiate", NULL, "fmi2_set_interface", args, 1, 2).status;
}

/* ---- FMI functions: creation and destruction ------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    char resources[PATH_MAX], uri[PATH_MAX + 16], error[MESSAGE_SIZE];
    Record record;
    const char *name = instanceName ? instanceName : "";
    if (instanceName == NULL || instanceName[0] == '\0' || functions == NULL) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: instanceName must be a non-empty string and "
                    "functions must not be NULL");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: fmuType %d is neither fmi2ModelExchange (0) nor "
                    "fmi2CoSimulation (1)", (int)fmuType);
        return NULL;
    }
    if (fmuResourceLocation == NULL || uri_to_path(fmuResourceLocation, resources, sizeof resources) != 0) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: fmuResourceLocation %s is not a file: URI "
                    "of the FMU's resources folder", fmuResourceLocation ? fmuResourceLocation : "(NULL)");
        return NULL;
    }
    if (read_record(resources, &record, error) != 0) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: %s", error);
        return NULL;
    }
    if (fmuGUID != NULL && fmuGUID[0] != '\0' && record.guid[0] && strcmp(fmuGUID, record.guid) != 0) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: GUID %s is not this FMU's (%s): the "
                    "modelDescription.xml read is not this binary's", fmuGUID, record.guid);
        return NULL;
    }
    if (set_up(&record, resources, error) != 0) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: %s", error);
        return NULL;
    }
    Instance *instance = calloc(1, sizeof *instance);
    if (instance == NULL || (instance->name = strdup(instanceName)) == NULL) {
        free(instance);
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    instance->host = *functions;
    instance->callbacks = *functions;
    instance->callbacks.logger = relay;
    instance->callbacks.componentEnvironment = instance;
    instance->logging_on = loggingOn == fmi2True;
    copy_string(instance->package, sizeof instance->package, record.package);
    snprintf(uri, sizeof uri, "file://%s", resources);       /* decoded: pythonfmu only decodes %20 */
    instance->type = fmuType;
    /* pythonfmu logs only with loggingOn: it gets fmi2True and `relay` filters; it creates Co-Simulation
     * instances only (the slave learns the host's fmuType below) */
    instance->inner = lib.fmi2Instantiate(instanceName, fmi2CoSimulation, fmuGUID, uri, &instance->callbacks, visible,
                                          fmi2True);
    if (instance->inner == NULL) {
        free(instance->name);
        free(instance);
        return NULL;
    }
    PyGILState_STATE gil = py.PyGILState_Ensure();
    fmi2Status told = tell_interface(instance);
    py.PyGILState_Release(gil);
    if (told > fmi2Warning) {                           /* a Model Exchange instance of a slave that cannot be one */
        lib.fmi2FreeInstance(instance->inner);
        free(instance->name);
        free(instance);
        return NULL;
    }
    if (register_instance(instance) != 0) {
        log_to_host(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        lib.fmi2FreeInstance(instance->inner);
        return NULL;
    }
    return instance;
}

/* A host's logger may call back into the instance that is logging (FMI 2.0 does not forbid it): every call
 * works, except freeing or resetting the instance under the call that is logging, which is refused. */
static int refused_inside_a_call(Instance *instance, const char *function)
{
    if (instance->busy == 0) return 0;
    emitf(instance, fmi2Error, "%s called while another call of this instance is in progress (from the host's "
          "logger); refused: call it after that call has returned", function);
    return 1;
}

void fmi2FreeInstance(fmi2Component c)
{
    Instance *instance = lookup(c, "fmi2FreeInstance");
    if (instance == NULL) return;                       /* e.g. freed before: nothing to do, nothing touched */
    if (refused_inside_a_call(instance, "fmi2FreeInstance")) return;
    unregister_instance(instance);
    lib.fmi2FreeInstance(instance->inner);
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject **objects[] = SLAVE_OBJECTS(instance);
    for (int i = 0; i < N_SLAVE_OBJECTS; i++) clear(objects[i]);
    clear_vrs(&instance->set_vrs);
    clear_vrs(&instance->get_vrs);
    for (size_t i = 0; i < instance->n_states; i++) py.Py_DecRef(instance->states[i]);   /* freed with it */
    py.PyGILState_Release(gil);
    free(instance->states);
    free(instance->name);
    free(instance);
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *instance = lookup(c, "fmi2Reset");
    if (instance == NULL) return fmi2Error;
    if (refused_inside_a_call(instance, "fmi2Reset")) return fmi2Error;
    instance->busy++;
    fmi2Status status = lib.fmi2Reset(instance->inner);       /* pythonfmu creates a new Python slave */
    PyGILState_STATE gil = py.PyGILState_Ensure();
    fmi2Status told = tell_interface(instance);
    py.PyGILState_Release(gil);
    instance->busy--;
    if (told > status) status = told;
    if (status > fmi2Warning) instance->failed = 1;
    return status;
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[])
{
    static const char *known[] = {"logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal",
                                  "logAll"};
    Instance *instance = lookup(c, "fmi2SetDebugLogging");
    if (instance == NULL) return fmi2Error;
    if (nCategories > 0 && (categories == NULL || nCategories > 5)) {
        emitf(instance, fmi2Error, "fmi2SetDebugLogging: %zu categories %s", nCategories,
              categories == NULL ? "in a NULL array" : "are more than this FMU's 5 (logStatusWarning, logStatusDiscard, "
              "logStatusError, logStatusFatal, logAll)");
        return fmi2Error;
    }
    for (size_t i = 0; i < nCategories; i++) {
        int found = 0;
        for (int k = 0; categories != NULL && categories[i] != NULL && k < 5; k++) found = found || !strcmp(categories[i], known[k]);
        if (!found) {
            emitf(instance, fmi2Error, "fmi2SetDebugLogging: %s is not a log category of this FMU (logStatusWarning, "
                  "logStatusDiscard, logStatusError, logStatusFatal, logAll)",
                  categories && categories[i] ? categories[i] : "(NULL)");
            return fmi2Error;
        }
    }
    instance->logging_on = loggingOn == fmi2True;   /* categories: every message goes to the host when on */
    return fmi2OK;
}

/* ---- FMI functions answered through the framework --------------------------------------------------- */
/* The instance for an FMI call, or return fmi2Error; a slave that is not an emcosim one: `forward`. */
#define BEGIN(function, forward)                                                                          \
    Instance *instance = lookup(c, #function);                                                            \
    if (instance == NULL) return fmi2Error;                                                               \
    if (instance->slave == NULL) {                                                                        \
        instance->busy++;                                                                                 \
        fmi2Status forwarded_ = (forward);                                                                \
        instance->busy--;                                                                                 \
        return forwarded_;                                                                                \
    }

#define NULL_ARRAYS(function, condition)                                                                  \
    if (condition) {                                                                                      \
        emitf(instance, fmi2Error, "%s: NULL array or pointer argument", #function);                       \
        return fmi2Error;                                                                                 \
    }

/* A count that is not the FMU's (header, point 6): refused before an element of the host's arrays is read.
 * The format (a string literal) and its arguments follow the condition. */
#define COUNT(function, condition, ...)                                                                   \
    if (condition) {                                                                                      \
        emitf(instance, fmi2Error, #function ": " __VA_ARGS__);                                           \
        return fmi2Error;                                                                                 \
    }

/* Input derivatives: FMI 2.0 sets no highest order and the FMUs accept every order >= 1 (fmus/derivatives.py);
 * masters send their sources' maxOutputDerivativeOrder, 1 to 3 in practice. More entries in one call than this
 * many per Real variable are refused as a count that cannot be the array's. */
#define INPUT_ORDERS_PER_CALL 16
#define STRING_(x) #x
#define STRING(x) STRING_(x)

/* nvr of a call on `n` variables of `type`: at most n (a host's duplicates beyond that are refused too). */
#define VR_COUNT(function, nvr, n, type)                                                                  \
    COUNT(function, (nvr) > (n), "%zu value references, more than this FMU's %zu " type " variables", (size_t)(nvr), \
          (size_t)(n))

static fmi2Status ask_status(Instance *instance, const char *function, PyObject *bound, const char *method,
                             PyObject *args[], int nargs)
{
    PyGILState_STATE gil = py.PyGILState_Ensure();
    Answer answer = ask(instance, function, bound, method, args, nargs, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    BEGIN(fmi2SetupExperiment, lib.fmi2SetupExperiment(instance->inner, toleranceDefined, tolerance, startTime,
                                                       stopTimeDefined, stopTime))
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[5] = {py.PyLong_FromLong(toleranceDefined), py.PyFloat_FromDouble(tolerance),
                         py.PyFloat_FromDouble(startTime), py.PyLong_FromLong(stopTimeDefined),
                         py.PyFloat_FromDouble(stopTime)};
    Answer answer = ask(instance, "fmi2SetupExperiment", NULL, "fmi2_setup_experiment", args, 5, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    BEGIN(fmi2EnterInitializationMode, lib.fmi2EnterInitializationMode(instance->inner))
    return ask_status(instance, "fmi2EnterInitializationMode", NULL, "fmi2_enter_initialization_mode", NULL, 0);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    BEGIN(fmi2ExitInitializationMode, lib.fmi2ExitInitializationMode(instance->inner))
    return ask_status(instance, "fmi2ExitInitializationMode", NULL, "fmi2_exit_initialization_mode", NULL, 0);
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    BEGIN(fmi2Terminate, lib.fmi2Terminate(instance->inner))
    return ask_status(instance, "fmi2Terminate", NULL, "fmi2_terminate", NULL, 0);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    BEGIN(fmi2DoStep, lib.fmi2DoStep(instance->inner, currentCommunicationPoint, communicationStepSize,
                                     noSetFMUStatePriorToCurrentPoint))
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[2] = {py.PyFloat_FromDouble(currentCommunicationPoint), py.PyFloat_FromDouble(communicationStepSize)};
    Answer answer = ask(instance, "fmi2DoStep", instance->do_step, NULL, args, 2, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    BEGIN(fmi2SetReal, lib.fmi2SetReal(instance->inner, vr, nvr, value))
    NULL_ARRAYS(fmi2SetReal, nvr > 0 && (vr == NULL || value == NULL))
    VR_COUNT(fmi2SetReal, nvr, instance->n_reals, "Real")
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[2] = {cached_vrs(&instance->set_vrs, vr, nvr), list_of_reals(value, nvr)};
    Answer answer = ask(instance, "fmi2SetReal", instance->set_real, NULL, args, 2, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    BEGIN(fmi2GetReal, lib.fmi2GetReal(instance->inner, vr, nvr, value))
    NULL_ARRAYS(fmi2GetReal, nvr > 0 && (vr == NULL || value == NULL))
    VR_COUNT(fmi2GetReal, nvr, instance->n_reals, "Real")
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {cached_vrs(&instance->get_vrs, vr, nvr)};
    fmi2Status status = copy_values(instance, "fmi2GetReal",
                                    ask(instance, "fmi2GetReal", instance->get_real, NULL, args, 1, 3), value, NULL, nvr);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    BEGIN(fmi2SetInteger, lib.fmi2SetInteger(instance->inner, vr, nvr, value))
    NULL_ARRAYS(fmi2SetInteger, nvr > 0 && (vr == NULL || value == NULL))
    VR_COUNT(fmi2SetInteger, nvr, instance->n_integers, "Integer")
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[2] = {list_of_vrs(vr, nvr), list_of_ints(value, nvr)};
    Answer answer = ask(instance, "fmi2SetInteger", NULL, "fmi2_set_integer", args, 2, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    BEGIN(fmi2GetInteger, lib.fmi2GetInteger(instance->inner, vr, nvr, value))
    NULL_ARRAYS(fmi2GetInteger, nvr > 0 && (vr == NULL || value == NULL))
    VR_COUNT(fmi2GetInteger, nvr, instance->n_integers, "Integer")
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {list_of_vrs(vr, nvr)};
    fmi2Status status = copy_values(instance, "fmi2GetInteger",
                                    ask(instance, "fmi2GetInteger", NULL, "fmi2_get_integer", args, 1, 3), NULL, value, nvr);
    py.PyGILState_Release(gil);
    return status;
}

/* emcosim slaves have Real and Integer variables only: nvr > 0 is refused (the arrays are not read). */
static fmi2Status no_such_variables(Instance *instance, const char *function, const char *type,
                                    const fmi2ValueReference vr[], size_t nvr)
{
    (void)vr;
    if (nvr == 0) return fmi2OK;
    emitf(instance, fmi2Error, "%s: %zu value references, but this FMU has no %s variables", function, nvr, type);
    return fmi2Error;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    BEGIN(fmi2GetBoolean, lib.fmi2GetBoolean(instance->inner, vr, nvr, value))
    return no_such_variables(instance, "fmi2GetBoolean", "Boolean", vr, nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    BEGIN(fmi2GetString, lib.fmi2GetString(instance->inner, vr, nvr, value))
    return no_such_variables(instance, "fmi2GetString", "String", vr, nvr);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    BEGIN(fmi2SetBoolean, lib.fmi2SetBoolean(instance->inner, vr, nvr, value))
    return no_such_variables(instance, "fmi2SetBoolean", "Boolean", vr, nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    BEGIN(fmi2SetString, lib.fmi2SetString(instance->inner, vr, nvr, value))
    return no_such_variables(instance, "fmi2SetString", "String", vr, nvr);
}

/* ---- FMU states: Python objects of the framework, registered per instance ---------------------------- */
/* A state `instance` gave out (registered), or NULL after logging why not. */
static PyObject *known_state(Instance *instance, const char *function, fmi2FMUstate state, size_t *index,
                             Instance **owner)
{
    size_t i = 0;
    Instance *o = state ? owner_of(state, &i) : NULL;
    if (o == NULL) {
        emitf(instance, fmi2Error, "%s: %p is not a state this FMU gave out (fmi2GetFMUstate or "
              "fmi2DeSerializeFMUstate), or it was freed", function, (void *)state);
        return NULL;
    }
    if (index) *index = i;
    if (owner) *owner = o;
    return (PyObject *)state;
}

/* Register a new state (the answer's value) and hand it out; fmi2Error if the answer has none. */
static fmi2Status give_state(Instance *instance, const char *function, Answer answer, fmi2FMUstate *state)
{
    if (answer.status <= fmi2Warning && answer.value != NULL && add_state(instance, answer.value) == 0) {
        *state = (fmi2FMUstate)answer.value;
        return answer.status;
    }
    if (answer.status <= fmi2Warning) emitf(instance, fmi2Error, "%s: no state", function);
    clear(&answer.value);
    return answer.status <= fmi2Warning ? fmi2Error : answer.status;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    BEGIN(fmi2GetFMUstate, lib.fmi2GetFMUstate(instance->inner, state))
    NULL_ARRAYS(fmi2GetFMUstate, state == NULL)
    size_t index = 0;
    PyGILState_STATE gil = py.PyGILState_Ensure();
    if (*state != NULL && owner_of(*state, &index) == instance) {
        remove_state(instance, index);                        /* FMI: a state passed in is overwritten */
        py.Py_DecRef((PyObject *)*state);
    }
    fmi2Status status = give_state(instance, "fmi2GetFMUstate",
                                   ask(instance, "fmi2GetFMUstate", NULL, "fmi2_get_fmu_state", NULL, 0, 3), state);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state)
{
    BEGIN(fmi2SetFMUstate, lib.fmi2SetFMUstate(instance->inner, state))
    PyObject *known = known_state(instance, "fmi2SetFMUstate", state, NULL, NULL);
    if (known == NULL) return fmi2Error;
    PyGILState_STATE gil = py.PyGILState_Ensure();
    py.Py_IncRef(known);
    PyObject *args[1] = {known};
    Answer answer = ask(instance, "fmi2SetFMUstate", NULL, "fmi2_set_fmu_state", args, 1, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    BEGIN(fmi2FreeFMUstate, lib.fmi2FreeFMUstate(instance->inner, state))
    NULL_ARRAYS(fmi2FreeFMUstate, state == NULL)
    if (*state == NULL) return fmi2OK;                        /* FMI: ignored */
    size_t index = 0;
    Instance *owner = NULL;
    PyObject *known = known_state(instance, "fmi2FreeFMUstate", *state, &index, &owner);
    if (known == NULL) return fmi2Error;
    remove_state(owner, index);
    PyGILState_STATE gil = py.PyGILState_Ensure();
    py.Py_DecRef(known);
    py.PyGILState_Release(gil);
    *state = NULL;
    return fmi2OK;
}

/* The serialized bytes of a known state (new reference), or NULL. GIL held. */
static PyObject *serialized(Instance *instance, const char *function, fmi2FMUstate state, fmi2Status *status)
{
    PyObject *known = known_state(instance, function, state, NULL, NULL);
    if (known == NULL) {
        *status = fmi2Error;
        return NULL;
    }
    py.Py_IncRef(known);
    PyObject *args[1] = {known};
    Answer answer = ask(instance, function, NULL, "fmi2_serialize_fmu_state", args, 1, 3);
    *status = answer.status;
    if (answer.status > fmi2Warning || answer.value == NULL || py.PyBytes_Size(answer.value) < 0) {
        py.PyErr_Clear();
        clear(&answer.value);
        if (*status <= fmi2Warning) *status = fmi2Error;
    }
    return answer.value;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    BEGIN(fmi2SerializedFMUstateSize, lib.fmi2SerializedFMUstateSize(instance->inner, state, size))
    NULL_ARRAYS(fmi2SerializedFMUstateSize, size == NULL)
    fmi2Status status;
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *bytes = serialized(instance, "fmi2SerializedFMUstateSize", state, &status);
    if (bytes != NULL) *size = (size_t)py.PyBytes_Size(bytes);
    clear(&bytes);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte serializedState[], size_t size)
{
    BEGIN(fmi2SerializeFMUstate, lib.fmi2SerializeFMUstate(instance->inner, state, serializedState, size))
    NULL_ARRAYS(fmi2SerializeFMUstate, serializedState == NULL)
    fmi2Status status;
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *bytes = serialized(instance, "fmi2SerializeFMUstate", state, &status);
    if (bytes != NULL) {
        size_t n = (size_t)py.PyBytes_Size(bytes);
        if (n > size) {
            emitf(instance, fmi2Error, "fmi2SerializeFMUstate: %zu bytes do not hold the state's %zu "
                  "(fmi2SerializedFMUstateSize)", size, n);
            status = fmi2Error;
        } else {
            memcpy(serializedState, py.PyBytes_AsString(bytes), n);
        }
    }
    clear(&bytes);
    py.PyGILState_Release(gil);
    return status;
}

/* A serialized state (fmus/state.py, format 2): STATE_HEADER, the format version (1 byte), the length of the
 * whole state (8 bytes, big endian), sha256 (32 bytes), the JSON payload. */
#define STATE_HEADER "emcosim FMU state\n"
#define STATE_FORMAT 2
#define STATE_LENGTH_AT (sizeof STATE_HEADER)            /* the header's bytes, then the version: 18 + 1 */
#define STATE_LENGTH_END (STATE_LENGTH_AT + 8)

/* '' if `size` bytes may be read from `data`: they start like a serialized state whose length is `size`
 * (read are the first STATE_LENGTH_END bytes, and only if size covers them); else why not. */
static const char *serialized_size_problem(const fmi2Byte *data, size_t size, char *why, size_t n)
{
    if (size < STATE_LENGTH_END || memcmp(data, STATE_HEADER, sizeof STATE_HEADER - 1) != 0) {
        snprintf(why, n, "%zu bytes that are not a serialized emcosim FMU state", size);
        return why;
    }
    if ((unsigned char)data[STATE_LENGTH_AT - 1] != STATE_FORMAT) {
        snprintf(why, n, "format version %d of the serialized state; this FMU reads version %d",
                 (unsigned char)data[STATE_LENGTH_AT - 1], STATE_FORMAT);
        return why;
    }
    unsigned long long length = 0;
    for (size_t i = STATE_LENGTH_AT; i < STATE_LENGTH_END; i++) length = length << 8 | (unsigned char)data[i];
    if (length != (unsigned long long)size) {
        snprintf(why, n, "size %zu is not the serialized state's length %llu (fmi2SerializedFMUstateSize): it "
                 "was cut, or the size is not its buffer's", size, length);
        return why;
    }
    return NULL;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size, fmi2FMUstate *state)
{
    BEGIN(fmi2DeSerializeFMUstate, lib.fmi2DeSerializeFMUstate(instance->inner, serializedState, size, state))
    NULL_ARRAYS(fmi2DeSerializeFMUstate, state == NULL || (serializedState == NULL && size > 0))
    char why[256];
    COUNT(fmi2DeSerializeFMUstate, serialized_size_problem(serializedState, size, why, sizeof why) != NULL, "%s", why)
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {py.PyBytes_FromStringAndSize(serializedState ? serializedState : "", (Py_ssize_t)size)};
    fmi2Status status = give_state(instance, "fmi2DeSerializeFMUstate",
                                   ask(instance, "fmi2DeSerializeFMUstate", NULL, "fmi2_deserialize_fmu_state", args, 1, 3),
                                   state);
    py.PyGILState_Release(gil);
    return status;
}

/* ---- derivatives ------------------------------------------------------------------------------------- */
static fmi2Status unsupported(Instance *instance, const char *function)
{
    emitf(instance, fmi2Error, "%s: not provided by this FMU's slave", function);
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    BEGIN(fmi2SetRealInputDerivatives, unsupported(instance, "fmi2SetRealInputDerivatives"))
    NULL_ARRAYS(fmi2SetRealInputDerivatives, nvr > 0 && (vr == NULL || order == NULL || value == NULL))
    COUNT(fmi2SetRealInputDerivatives, nvr > INPUT_ORDERS_PER_CALL * instance->n_reals,
          "%zu entries, more than " STRING(INPUT_ORDERS_PER_CALL) " orders for each of this FMU's %zu Real variables",
          nvr, instance->n_reals)
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[3] = {list_of_vrs(vr, nvr), list_of_ints(order, nvr), list_of_reals(value, nvr)};
    Answer answer = ask(instance, "fmi2SetRealInputDerivatives", NULL, "fmi2_set_real_input_derivatives", args, 3, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    BEGIN(fmi2GetRealOutputDerivatives, unsupported(instance, "fmi2GetRealOutputDerivatives"))
    NULL_ARRAYS(fmi2GetRealOutputDerivatives, nvr > 0 && (vr == NULL || order == NULL || value == NULL))
    COUNT(fmi2GetRealOutputDerivatives, nvr > instance->n_reals * instance->max_output_order, "%zu entries, more "
          "than this FMU's %zu Real variables times its maxOutputDerivativeOrder %zu", nvr, instance->n_reals,
          instance->max_output_order)
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[2] = {list_of_vrs(vr, nvr), list_of_ints(order, nvr)};
    Answer answer = ask(instance, "fmi2GetRealOutputDerivatives", NULL, "fmi2_get_real_output_derivatives", args, 2, 3);
    fmi2Status status = answer.status <= fmi2Warning
        ? copy_values(instance, "fmi2GetRealOutputDerivatives", answer, value, NULL, nvr) : answer.status;
    if (answer.status > fmi2Warning) clear(&answer.value);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    BEGIN(fmi2GetDirectionalDerivative, unsupported(instance, "fmi2GetDirectionalDerivative"))
    NULL_ARRAYS(fmi2GetDirectionalDerivative, (nUnknown > 0 && (vUnknown_ref == NULL || dvUnknown == NULL)) ||
                                              (nKnown > 0 && (vKnown_ref == NULL || dvKnown == NULL)))
    VR_COUNT(fmi2GetDirectionalDerivative, nUnknown, instance->n_reals, "Real")
    VR_COUNT(fmi2GetDirectionalDerivative, nKnown, instance->n_reals, "Real")
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[3] = {list_of_vrs(vUnknown_ref, nUnknown), list_of_vrs(vKnown_ref, nKnown),
                         list_of_reals(dvKnown, nKnown)};
    Answer answer = ask(instance, "fmi2GetDirectionalDerivative", NULL, "fmi2_get_directional_derivative", args, 3, 3);
    fmi2Status status = answer.status <= fmi2Warning
        ? copy_values(instance, "fmi2GetDirectionalDerivative", answer, dvUnknown, NULL, nUnknown) : answer.status;
    if (answer.status > fmi2Warning) clear(&answer.value);
    py.PyGILState_Release(gil);
    return status;
}

/* ---- Model Exchange (fmus/model_exchange.py: the state machine and the checks) ------------------------ */
/* Copy a list answer of n values (fmi2OK or fmi2Warning), else leave `values` alone. GIL held. */
static fmi2Status list_answer(Instance *instance, const char *function, Answer answer, fmi2Real values[], size_t n)
{
    if (answer.status <= fmi2Warning) return copy_values(instance, function, answer, values, NULL, n);
    clear(&answer.value);
    return answer.status;
}

/* Copy the ints of a tuple answer into `flags` (n of them) and the real at index `real_at` into *real. */
static void tuple_answer(Answer answer, int flags[], int n, int real_at, fmi2Real *real)
{
    for (int i = 0; answer.value != NULL && i < n; i++)
        flags[i] = (int)py.PyLong_AsLong(py.PyTuple_GetItem(answer.value, i));
    if (answer.value != NULL && real != NULL) *real = py.PyFloat_AsDouble(py.PyTuple_GetItem(answer.value, real_at));
    py.PyErr_Clear();
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time)
{
    BEGIN(fmi2SetTime, unsupported(instance, "fmi2SetTime"))
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {py.PyFloat_FromDouble(time)};
    Answer answer = ask(instance, "fmi2SetTime", instance->set_time, NULL, args, 1, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    BEGIN(fmi2SetContinuousStates, unsupported(instance, "fmi2SetContinuousStates"))
    NULL_ARRAYS(fmi2SetContinuousStates, nx > 0 && x == NULL)
    COUNT(fmi2SetContinuousStates, nx != instance->nx, "%zu values for %zu states", nx, instance->nx)
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {list_of_reals(x, nx)};
    Answer answer = ask(instance, "fmi2SetContinuousStates", instance->set_states, NULL, args, 1, 2);
    py.PyGILState_Release(gil);
    return answer.status;
}

/* fmi2GetContinuousStates, fmi2GetDerivatives, fmi2GetEventIndicators, fmi2GetNominalsOfContinuousStates:
 * the slave's method answers (status, values, message) for n values. */
static fmi2Status get_vector(Instance *instance, const char *function, PyObject *bound, const char *method,
                             fmi2Real values[], size_t n, size_t fmu_n, const char *what)
{
    if (n > 0 && values == NULL) {
        emitf(instance, fmi2Error, "%s: NULL array or pointer argument", function);
        return fmi2Error;
    }
    if (n != fmu_n) {
        emitf(instance, fmi2Error, "%s: %zu values asked for, the FMU has %zu %s", function, n, fmu_n, what);
        return fmi2Error;
    }
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {py.PyLong_FromUnsignedLong((unsigned long)n)};
    fmi2Status status = list_answer(instance, function, ask(instance, function, bound, method, args, 1, 3), values, n);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    BEGIN(fmi2GetContinuousStates, unsupported(instance, "fmi2GetContinuousStates"))
    return get_vector(instance, "fmi2GetContinuousStates", instance->get_states, NULL, x, nx, instance->nx,
                      "states");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx)
{
    BEGIN(fmi2GetDerivatives, unsupported(instance, "fmi2GetDerivatives"))
    return get_vector(instance, "fmi2GetDerivatives", instance->get_derivatives, NULL, derivatives, nx,
                      instance->nx, "states");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni)
{
    BEGIN(fmi2GetEventIndicators, unsupported(instance, "fmi2GetEventIndicators"))
    return get_vector(instance, "fmi2GetEventIndicators", instance->get_indicators, NULL, eventIndicators, ni,
                      instance->ni, "event indicators");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx)
{
    BEGIN(fmi2GetNominalsOfContinuousStates, unsupported(instance, "fmi2GetNominalsOfContinuousStates"))
    return get_vector(instance, "fmi2GetNominalsOfContinuousStates", NULL, "fmi2_get_nominals_of_continuous_states",
                      x_nominal, nx, instance->nx, "states");
}

fmi2Status fmi2EnterEventMode(fmi2Component c)
{
    BEGIN(fmi2EnterEventMode, unsupported(instance, "fmi2EnterEventMode"))
    return ask_status(instance, "fmi2EnterEventMode", NULL, "fmi2_enter_event_mode", NULL, 0);
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c)
{
    BEGIN(fmi2EnterContinuousTimeMode, unsupported(instance, "fmi2EnterContinuousTimeMode"))
    return ask_status(instance, "fmi2EnterContinuousTimeMode", NULL, "fmi2_enter_continuous_time_mode", NULL, 0);
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo)
{
    BEGIN(fmi2NewDiscreteStates, unsupported(instance, "fmi2NewDiscreteStates"))
    NULL_ARRAYS(fmi2NewDiscreteStates, eventInfo == NULL)
    PyGILState_STATE gil = py.PyGILState_Ensure();
    Answer answer = ask(instance, "fmi2NewDiscreteStates", NULL, "fmi2_new_discrete_states", NULL, 0, 3);
    int flags[5] = {0, 0, 0, 0, 0};
    fmi2Real next = 0.0;
    tuple_answer(answer, flags, 5, 5, &next);
    clear(&answer.value);
    py.PyGILState_Release(gil);
    eventInfo->newDiscreteStatesNeeded = flags[0] ? fmi2True : fmi2False;
    eventInfo->terminateSimulation = flags[1] ? fmi2True : fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = flags[2] ? fmi2True : fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = flags[3] ? fmi2True : fmi2False;
    eventInfo->nextEventTimeDefined = flags[4] ? fmi2True : fmi2False;
    eventInfo->nextEventTime = next;
    return answer.status;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    BEGIN(fmi2CompletedIntegratorStep, unsupported(instance, "fmi2CompletedIntegratorStep"))
    NULL_ARRAYS(fmi2CompletedIntegratorStep, enterEventMode == NULL || terminateSimulation == NULL)
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[1] = {py.PyLong_FromLong(noSetFMUStatePriorToCurrentPoint)};
    Answer answer = ask(instance, "fmi2CompletedIntegratorStep", NULL, "fmi2_completed_integrator_step", args, 1, 3);
    int flags[2] = {0, 0};
    tuple_answer(answer, flags, 2, -1, NULL);
    clear(&answer.value);
    py.PyGILState_Release(gil);
    *enterEventMode = flags[0] ? fmi2True : fmi2False;
    *terminateSimulation = flags[1] ? fmi2True : fmi2False;
    return answer.status;
}

/* ---- status inquiries (doStep is never asynchronous) ---------------------------------------------------- */
/* A Co-Simulation function called on a Model Exchange instance: fmi2Error (the slave refuses fmi2DoStep and the
 * input and output derivatives itself). */
#define CS_ONLY(function)                                                                                 \
    if (instance->type == fmi2ModelExchange) {                                                            \
        emitf(instance, fmi2Error, "%s: this instance is a Model Exchange one (fmi2Instantiate's fmuType); "  \
              "Co-Simulation functions are refused", #function);                                          \
        return fmi2Error;                                                                                 \
    }

fmi2Status fmi2CancelStep(fmi2Component c)
{
    BEGIN(fmi2CancelStep, lib.fmi2CancelStep(instance->inner))
    CS_ONLY(fmi2CancelStep)
    emitf(instance, fmi2Error, "fmi2CancelStep: no asynchronous fmi2DoStep to cancel (this FMU never returns fmi2Pending)");
    return fmi2Error;
}

static fmi2Status not_available(Instance *instance, const char *function, int kind)
{
    emitf(instance, fmi2Discard, "%s: status kind %d is not available (doStep is never asynchronous)", function, kind);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    BEGIN(fmi2GetStatus, lib.fmi2GetStatus(instance->inner, s, value))
    CS_ONLY(fmi2GetStatus)
    return not_available(instance, "fmi2GetStatus", (int)s);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    BEGIN(fmi2GetRealStatus, lib.fmi2GetRealStatus(instance->inner, s, value))
    CS_ONLY(fmi2GetRealStatus)
    NULL_ARRAYS(fmi2GetRealStatus, value == NULL)
    if (s != fmi2LastSuccessfulTime) return not_available(instance, "fmi2GetRealStatus", (int)s);
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *time = py.PyObject_GetAttrString(instance->slave, "time");   /* the end of the last successful step */
    *value = time ? py.PyFloat_AsDouble(time) : 0.0;
    clear(&time);
    py.PyErr_Clear();
    py.PyGILState_Release(gil);
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    BEGIN(fmi2GetIntegerStatus, lib.fmi2GetIntegerStatus(instance->inner, s, value))
    CS_ONLY(fmi2GetIntegerStatus)
    return not_available(instance, "fmi2GetIntegerStatus", (int)s);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    BEGIN(fmi2GetBooleanStatus, lib.fmi2GetBooleanStatus(instance->inner, s, value))
    CS_ONLY(fmi2GetBooleanStatus)
    NULL_ARRAYS(fmi2GetBooleanStatus, value == NULL)
    if (s != fmi2Terminated) return not_available(instance, "fmi2GetBooleanStatus", (int)s);
    *value = fmi2False;           /* never asks to end the simulation: after fmi2Discard the state is kept */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    BEGIN(fmi2GetStringStatus, lib.fmi2GetStringStatus(instance->inner, s, value))
    CS_ONLY(fmi2GetStringStatus)
    return not_available(instance, "fmi2GetStringStatus", (int)s);
}
