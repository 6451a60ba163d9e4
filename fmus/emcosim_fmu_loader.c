/* The binary of every emcosim FMU: binaries/linux64/<modelIdentifier>.so (built by build.py).
 *
 * pythonfmu 0.7.0's export library (shipped beside this file as libpythonfmu-export.so) runs the FMU's
 * Python slave, but it expects a host that already has Python: its Python C-API symbols are undefined,
 * so a plain C host fails at dlopen, and a host that preloads libpython still has to point Python at
 * numpy and scipy. It also answers "not supported" to the three derivative functions. This loader:
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
 *  3. Forwards every fmi2 function to pythonfmu's library, and answers fmi2SetRealInputDerivatives,
 *     fmi2GetRealOutputDerivatives and fmi2GetDirectionalDerivative by calling the framework's methods
 *     (em_fmu_framework.EMSlave.fmi2_*) on the instance's Python slave, with the GIL held.
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
    X(PyGILState_Ensure) X(PyGILState_Release) X(PyImport_ImportModule) X(PyObject_GetAttrString)         \
    X(PyObject_CallFunctionObjArgs) X(PyObject_Str) X(PyErr_Fetch) X(PyErr_Occurred) X(Py_DecRef)         \
    X(PyList_New) X(PyList_SetItem) X(PyList_Size) X(PyList_GetItem)                     \
    X(PyTuple_Size) X(PyTuple_GetItem) X(PyLong_FromLong)       \
    X(PyLong_FromUnsignedLong) X(PyLong_AsLong) X(PyFloat_FromDouble) X(PyFloat_AsDouble)                 \
    X(PyUnicode_FromString) X(PyUnicode_AsUTF8) X(PyImport_GetModule)

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

/* ---- state of this library (one per FMU: every FMU ships its own copy) ------------------------------ */
static pthread_mutex_t setup_lock = PTHREAD_MUTEX_INITIALIZER;
static int setup_done;                       /* Python and pythonfmu's library are ready */
static char setup_error[MESSAGE_SIZE];       /* or why not (then every fmi2Instantiate reports it) */

typedef struct {
    fmi2Component inner;                     /* pythonfmu's instance */
    PyObject *slave;                         /* the EMSlave (a strong reference), or NULL */
    fmi2CallbackFunctions callbacks;         /* the host's, copied: pythonfmu keeps a pointer to them */
    char *name;
    char package[128];                       /* the bundle package (em_fmu_framework is found there) */
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
} Record;

/* ---- logging through the host's callback ------------------------------------------------------------ */
static const char *category(fmi2Status status)
{
    static const char *names[] = {"logStatusOK", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                  "logStatusFatal", "logStatusPending"};
    return status <= fmi2Pending ? names[status] : "logAll";
}

static void log_to_host(const fmi2CallbackFunctions *callbacks, const char *instance, fmi2Status status,
                        const char *format, ...)
{
    char message[MESSAGE_SIZE], escaped[2 * MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    /* the logger's message is a printf format (FMI 2.0); hosts that do not format it (fmpy) show it as is */
    size_t n = 0;
    for (const char *p = message; *p; p++) {
        if (*p == '%') escaped[n++] = '%';
        escaped[n++] = *p;
    }
    escaped[n] = '\0';
    if (callbacks != NULL && callbacks->logger != NULL)
        callbacks->logger(callbacks->componentEnvironment, instance ? instance : "", status, category(status), escaped);
    else
        fprintf(stderr, "[%s] %s\n", instance ? instance : "", message);
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

/* Python running, the environment checked, pythonfmu loaded: once per process and FMU binary, except the
 * checks (per instance: another FMU may have loaded something in between). */
static int set_up(const Record *record, const char *resources, char *error)
{
    pthread_mutex_lock(&setup_lock);
    int started = 0;
    if (!setup_done && !setup_error[0]) {
        int (*is_initialized)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
        if (is_initialized != NULL && is_initialized()) {                 /* the host's Python (fmpy, ...) */
            const char *missing = bind_python(RTLD_DEFAULT);
            if (missing) snprintf(setup_error, sizeof setup_error, "the host's Python lacks %s", missing);
        } else if (start_python(record, setup_error) == 0) {
            started = 1;
        }
        if (!setup_error[0]) load_pythonfmu(setup_error);
        setup_done = !setup_error[0];
    }
    pthread_mutex_unlock(&setup_lock);
    if (!setup_done) {
        copy_string(error, MESSAGE_SIZE, setup_error);
        return -1;
    }
    return check_environment(record, resources, started, error);
}

/* ---- the Python slave of an instance ------------------------------------------------------------------ */
/* The EMSlave pythonfmu constructed last on this thread (em_fmu_framework.take_new_slave). GIL held. */
static PyObject *take_slave(const char *package)
{
    char module[256];
    snprintf(module, sizeof module, "%s.em_fmu_framework", package);
    PyObject *framework = py.PyImport_ImportModule(module);
    PyObject *take = framework ? py.PyObject_GetAttrString(framework, "take_new_slave") : NULL;
    PyObject *slave = take ? py.PyObject_CallFunctionObjArgs(take, NULL) : NULL;
    if (framework) py.Py_DecRef(framework);
    if (take) py.Py_DecRef(take);
    if (slave == NULL) {
        char text[MESSAGE_SIZE];
        python_error_text(text, sizeof text);
        fprintf(stderr, "emcosim FMU loader: %s.take_new_slave failed: %s\n", module, text);
    }
    return slave;
}

static Instance *instance_of(fmi2Component c)
{
    return (Instance *)c;
}

/* ---- FMI functions ------------------------------------------------------------------------------------ */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    char resources[PATH_MAX], uri[PATH_MAX + 16], error[MESSAGE_SIZE];
    Record record;
    if (functions == NULL || instanceName == NULL) {
        log_to_host(functions, instanceName, fmi2Error, "fmi2Instantiate: instanceName and functions must not be NULL");
        return NULL;
    }
    if (fmuResourceLocation == NULL || uri_to_path(fmuResourceLocation, resources, sizeof resources) != 0) {
        log_to_host(functions, instanceName, fmi2Error, "fmi2Instantiate: fmuResourceLocation %s is not a file: URI "
                    "of the FMU's resources folder", fmuResourceLocation ? fmuResourceLocation : "(NULL)");
        return NULL;
    }
    if (read_record(resources, &record, error) != 0 || set_up(&record, resources, error) != 0) {
        log_to_host(functions, instanceName, fmi2Error, "fmi2Instantiate: %s", error);
        return NULL;
    }
    Instance *instance = calloc(1, sizeof *instance);
    if (instance == NULL || (instance->name = strdup(instanceName)) == NULL) {
        free(instance);
        log_to_host(functions, instanceName, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    instance->callbacks = *functions;
    copy_string(instance->package, sizeof instance->package, record.package);
    snprintf(uri, sizeof uri, "file://%s", resources);       /* decoded: pythonfmu only decodes %20 */
    instance->inner = lib.fmi2Instantiate(instanceName, fmuType, fmuGUID, uri, &instance->callbacks, visible, loggingOn);
    if (instance->inner == NULL) {
        free(instance->name);
        free(instance);
        return NULL;
    }
    PyGILState_STATE gil = py.PyGILState_Ensure();
    instance->slave = take_slave(record.package);
    py.PyGILState_Release(gil);
    return instance;
}

void fmi2FreeInstance(fmi2Component c)
{
    Instance *instance = instance_of(c);
    if (instance == NULL) return;
    lib.fmi2FreeInstance(instance->inner);
    if (instance->slave != NULL) {
        PyGILState_STATE gil = py.PyGILState_Ensure();
        py.Py_DecRef(instance->slave);
        py.PyGILState_Release(gil);
    }
    free(instance->name);
    free(instance);
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *instance = instance_of(c);
    fmi2Status status = lib.fmi2Reset(instance->inner);       /* pythonfmu creates a new Python slave */
    PyGILState_STATE gil = py.PyGILState_Ensure();
    if (instance->slave != NULL) py.Py_DecRef(instance->slave);
    instance->slave = take_slave(instance->package);
    py.PyGILState_Release(gil);
    return status;
}

/* ---- derivatives: the framework's fmi2_* methods ---------------------------------------------------- */
static PyObject *list_of_vrs(const fmi2ValueReference *vr, size_t n)
{
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) py.PyList_SetItem(list, (Py_ssize_t)i, py.PyLong_FromUnsignedLong(vr[i]));
    return list;
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

/* Call slave.<method>(*args) -> (status, message), or (status, values, message) when `out` is given: copy
 * the n values into out, log the message with the status. Releases the arguments. GIL held. */
static fmi2Status call_slave(Instance *instance, const char *function, const char *method, PyObject *args[3],
                             fmi2Real *out, size_t n)
{
    char text[MESSAGE_SIZE];
    fmi2Status status = fmi2Error;
    int nargs = args[2] ? 3 : 2;
    PyObject *bound = NULL, *result = NULL;
    if (instance->slave == NULL) {
        log_to_host(&instance->callbacks, instance->name, fmi2Error, "%s: the Python slave of this instance is not "
                    "known (see the message of fmi2Instantiate)", function);
        goto done;
    }
    if (args[0] && args[1] && (bound = py.PyObject_GetAttrString(instance->slave, method)) != NULL)
        result = py.PyObject_CallFunctionObjArgs(bound, args[0], args[1], args[2], NULL);
    Py_ssize_t size = result ? py.PyTuple_Size(result) : -1;
    if (size != (out ? 3 : 2)) {
        if (result == NULL || py.PyErr_Occurred()) python_error_text(text, sizeof text);
        else snprintf(text, sizeof text, "%s returned no tuple of %d items", method, out ? 3 : 2);
        log_to_host(&instance->callbacks, instance->name, fmi2Error, "%s: %s", function, text);
        goto done;
    }
    long code = py.PyLong_AsLong(py.PyTuple_GetItem(result, 0));
    const char *message = py.PyUnicode_AsUTF8(py.PyTuple_GetItem(result, size - 1));
    status = code >= fmi2OK && code <= fmi2Fatal ? (fmi2Status)code : fmi2Error;
    if (out && status <= fmi2Warning) {
        PyObject *values = py.PyTuple_GetItem(result, 1);
        if (py.PyList_Size(values) != (Py_ssize_t)n) {
            status = fmi2Error;
            message = "the slave returned a wrong number of values";
        } else {
            for (size_t i = 0; i < n; i++) out[i] = py.PyFloat_AsDouble(py.PyList_GetItem(values, (Py_ssize_t)i));
        }
    }
    if (py.PyErr_Occurred()) {
        python_error_text(text, sizeof text);
        status = fmi2Error;
        message = text;
    }
    if (message != NULL && message[0])
        log_to_host(&instance->callbacks, instance->name, status, "%s", message);
    else if (status > fmi2Warning)
        log_to_host(&instance->callbacks, instance->name, status, "%s failed", function);
done:
    if (py.PyErr_Occurred()) python_error_text(text, sizeof text);
    if (bound) py.Py_DecRef(bound);
    if (result) py.Py_DecRef(result);
    for (int i = 0; i < nargs; i++)
        if (args[i]) py.Py_DecRef(args[i]);
    return status;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    Instance *instance = instance_of(c);
    if (nvr > 0 && (vr == NULL || order == NULL || value == NULL)) {
        log_to_host(&instance->callbacks, instance->name, fmi2Error, "fmi2SetRealInputDerivatives: NULL array");
        return fmi2Error;
    }
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[3] = {list_of_vrs(vr, nvr), list_of_ints(order, nvr), list_of_reals(value, nvr)};
    fmi2Status status = call_slave(instance, "fmi2SetRealInputDerivatives", "fmi2_set_real_input_derivatives",
                                   args, NULL, 0);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    Instance *instance = instance_of(c);
    if (nvr > 0 && (vr == NULL || order == NULL || value == NULL)) {
        log_to_host(&instance->callbacks, instance->name, fmi2Error, "fmi2GetRealOutputDerivatives: NULL array");
        return fmi2Error;
    }
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[3] = {list_of_vrs(vr, nvr), list_of_ints(order, nvr), NULL};
    fmi2Status status = call_slave(instance, "fmi2GetRealOutputDerivatives", "fmi2_get_real_output_derivatives",
                                   args, value, nvr);
    py.PyGILState_Release(gil);
    return status;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    Instance *instance = instance_of(c);
    if ((nUnknown > 0 && (vUnknown_ref == NULL || dvUnknown == NULL)) ||
        (nKnown > 0 && (vKnown_ref == NULL || dvKnown == NULL))) {
        log_to_host(&instance->callbacks, instance->name, fmi2Error, "fmi2GetDirectionalDerivative: NULL array");
        return fmi2Error;
    }
    PyGILState_STATE gil = py.PyGILState_Ensure();
    PyObject *args[3] = {list_of_vrs(vUnknown_ref, nUnknown), list_of_vrs(vKnown_ref, nKnown),
                         list_of_reals(dvKnown, nKnown)};
    fmi2Status status = call_slave(instance, "fmi2GetDirectionalDerivative", "fmi2_get_directional_derivative",
                                   args, dvUnknown, nUnknown);
    py.PyGILState_Release(gil);
    return status;
}

/* ---- forwarded as they are ---------------------------------------------------------------------------- */
#define INNER(c) (instance_of(c)->inner)

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[])
{
    return lib.fmi2SetDebugLogging(INNER(c), loggingOn, nCategories, categories);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    return lib.fmi2SetupExperiment(INNER(c), toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return lib.fmi2EnterInitializationMode(INNER(c)); }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return lib.fmi2ExitInitializationMode(INNER(c)); }
fmi2Status fmi2Terminate(fmi2Component c) { return lib.fmi2Terminate(INNER(c)); }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    return lib.fmi2GetReal(INNER(c), vr, nvr, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    return lib.fmi2GetInteger(INNER(c), vr, nvr, value);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    return lib.fmi2GetBoolean(INNER(c), vr, nvr, value);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    return lib.fmi2GetString(INNER(c), vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    return lib.fmi2SetReal(INNER(c), vr, nvr, value);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    return lib.fmi2SetInteger(INNER(c), vr, nvr, value);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    return lib.fmi2SetBoolean(INNER(c), vr, nvr, value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    return lib.fmi2SetString(INNER(c), vr, nvr, value);
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) { return lib.fmi2GetFMUstate(INNER(c), state); }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) { return lib.fmi2SetFMUstate(INNER(c), state); }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) { return lib.fmi2FreeFMUstate(INNER(c), state); }

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    return lib.fmi2SerializedFMUstateSize(INNER(c), state, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size)
{
    return lib.fmi2SerializeFMUstate(INNER(c), state, bytes, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state)
{
    return lib.fmi2DeSerializeFMUstate(INNER(c), bytes, size, state);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    return lib.fmi2DoStep(INNER(c), currentCommunicationPoint, communicationStepSize, noSetFMUStatePriorToCurrentPoint);
}

fmi2Status fmi2CancelStep(fmi2Component c) { return lib.fmi2CancelStep(INNER(c)); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    return lib.fmi2GetStatus(INNER(c), s, value);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    return lib.fmi2GetRealStatus(INNER(c), s, value);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    return lib.fmi2GetIntegerStatus(INNER(c), s, value);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    return lib.fmi2GetBooleanStatus(INNER(c), s, value);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    return lib.fmi2GetStringStatus(INNER(c), s, value);
}
