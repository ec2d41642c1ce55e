/* The compiled hot path of one noise pipeline (noise_models._hot): what noise_models.fused.hot_pipe and
 * SignalCorruptor._hot_noisy_lag do on every step, as two callable types, so that a step costs one C call instead of a
 * Python closure and numpy's ufunc dispatch. Optional: noise_models.compiled picks these when the extension is built
 * and the Python closures otherwise; tests/test_compiled.py pins them bitwise to the closures.
 *
 * The state they step is the pipeline's own (its attributes ``r``, ``rows``, ``simple``; the observation ring the
 * corruptor holds), read and written on every call exactly as the closures do: anything this file does not handle
 * itself (a new block, an array that is not a plain 1-D C-contiguous one of the rows' dtype, a guarded clip) is
 * handed to the Python code (the closure, the pipeline's own __call__ or numpy's +) with the state untouched.
 *
 * Arithmetic: one IEEE add per entry in the signal's dtype (float32 or float64), what numpy's add loop computes,
 * then numpy's clip of a floating type, min(max(x, low), high) with NaN in x kept (numpy/_core/src/umath/clip.cpp).
 * Compiled without FMA contraction or fast-math (setup.py).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stddef.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

/* Copies answer as a Python function does (copy.copy and copy.deepcopy keep functions as they are): the object
 * itself, so that whatever deep-copied the closures before deep-copies this. */
static PyObject *
same_object(PyObject *self, PyObject *Py_UNUSED(args))
{
    return Py_NewRef(self);
}


static PyObject *s_r, *s_rows, *s_simple, *s_copy;

/* A plain 1-D array of n entries of dtype typenum: exactly an ndarray (a subclass may override +), aligned,
 * C-contiguous, native byte order. */
static int
plain(PyObject *o, int typenum, npy_intp n)
{
    if (!PyArray_CheckExact(o)) {
        return 0;
    }
    PyArrayObject *a = (PyArrayObject *)o;
    return PyArray_NDIM(a) == 1 && PyArray_DIM(a, 0) == n && PyArray_TYPE(a) == typenum &&
           PyArray_ISCARRAY_RO(a) && PyArray_ISNOTSWAPPED(a);
}

/* A new 1-D array x + row (both plain, of typenum), then clipped to [low, high] when low is not NULL. */
static PyObject *
add_rows(PyObject *x, PyObject *row, int typenum, npy_intp n, PyObject *low, PyObject *high)
{
    PyObject *out = PyArray_SimpleNew(1, &n, typenum);
    if (out == NULL) {
        return NULL;
    }
    npy_intp i;
    if (typenum == NPY_FLOAT64) {
        const double *a = (const double *)PyArray_DATA((PyArrayObject *)x);
        const double *b = (const double *)PyArray_DATA((PyArrayObject *)row);
        double *w = (double *)PyArray_DATA((PyArrayObject *)out);
        for (i = 0; i < n; i++) {
            w[i] = a[i] + b[i];
        }
        if (low != NULL) {
            const double *lo = (const double *)PyArray_DATA((PyArrayObject *)low);
            const double *hi = (const double *)PyArray_DATA((PyArrayObject *)high);
            for (i = 0; i < n; i++) {
                double v = w[i];
                v = isnan(v) ? v : (v > lo[i] ? v : lo[i]);
                v = isnan(v) ? v : (v < hi[i] ? v : hi[i]);
                w[i] = v;
            }
        }
    }
    else {
        const float *a = (const float *)PyArray_DATA((PyArrayObject *)x);
        const float *b = (const float *)PyArray_DATA((PyArrayObject *)row);
        float *w = (float *)PyArray_DATA((PyArrayObject *)out);
        for (i = 0; i < n; i++) {
            w[i] = a[i] + b[i];
        }
        if (low != NULL) {
            const float *lo = (const float *)PyArray_DATA((PyArrayObject *)low);
            const float *hi = (const float *)PyArray_DATA((PyArrayObject *)high);
            for (i = 0; i < n; i++) {
                float v = w[i];
                v = isnan(v) ? v : (v > lo[i] ? v : lo[i]);
                v = isnan(v) ? v : (v < hi[i] ? v : hi[i]);
                w[i] = v;
            }
        }
    }
    return out;
}

/* An int attribute of the pipeline (r, simple); -1 with an exception set on failure. */
static long
int_attr(PyObject *obj, PyObject *name)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    long out = PyLong_AsLong(v);
    Py_DECREF(v);
    return out;
}

/* The pipeline's row r (a new reference), or NULL with no exception when rows is not a list that long. */
static PyObject *
row_at(PyObject *pipe, long r, int *failed)
{
    PyObject *rows = PyObject_GetAttr(pipe, s_rows);
    *failed = rows == NULL;
    if (rows == NULL) {
        return NULL;
    }
    PyObject *row = NULL;
    if (PyList_CheckExact(rows) && r >= 0 && r < PyList_GET_SIZE(rows)) {
        row = PyList_GET_ITEM(rows, r);
        Py_INCREF(row);
    }
    Py_DECREF(rows);
    return row;
}

static int
set_r(PyObject *pipe, long r)
{
    PyObject *v = PyLong_FromLong(r);
    if (v == NULL) {
        return -1;
    }
    int rc = PyObject_SetAttr(pipe, s_r, v);
    Py_DECREF(v);
    return rc;
}

/* Checks the clip bounds given to a constructor: None, or plain arrays of the signal's dtype and size. */
static int
bounds_ok(PyObject *low, PyObject *high, int typenum, npy_intp n)
{
    if (low == Py_None && high == Py_None) {
        return 1;
    }
    return low != Py_None && high != Py_None && plain(low, typenum, n) && plain(high, typenum, n);
}

static int
typenum_of(PyObject *dtype, int *typenum)
{
    PyArray_Descr *descr = NULL;
    if (!PyArray_DescrConverter(dtype, &descr)) {
        return -1;
    }
    *typenum = descr->type_num;
    int native = PyArray_ISNBO(descr->byteorder);
    Py_DECREF(descr);
    if ((*typenum != NPY_FLOAT64 && *typenum != NPY_FLOAT32) || !native) {
        PyErr_SetString(PyExc_ValueError, "`dtype` must be float32 or float64 in native byte order.");
        return -1;
    }
    return 0;
}

/* The signal of a call (x) / (x, now) / (x, now=...) / (obs=..., now=...), as the Python closures take them
 * (``name``, or ``alias`` when not NULL: the first parameter's); NULL with TypeError otherwise. ``now`` is not read. */
static PyObject *
signal_arg(PyObject *const *args, size_t nargsf, PyObject *kwnames, const char *name, const char *alias)
{
    Py_ssize_t nargs = PyVectorcall_NARGS(nargsf);
    PyObject *x = nargs >= 1 ? args[0] : NULL;
    int have_now = nargs >= 2;
    Py_ssize_t nkw = kwnames == NULL ? 0 : PyTuple_GET_SIZE(kwnames);
    if (nargs > 2) {
        PyErr_Format(PyExc_TypeError, "takes at most 2 arguments (%zd given)", nargs + nkw);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < nkw; i++) {
        PyObject *key = PyTuple_GET_ITEM(kwnames, i);
        int named = PyUnicode_CompareWithASCIIString(key, name) == 0 ||
                    (alias != NULL && PyUnicode_CompareWithASCIIString(key, alias) == 0);
        if (named && x == NULL) {
            x = args[nargs + i];
        }
        else if (PyUnicode_CompareWithASCIIString(key, "now") == 0 && !have_now) {
            have_now = 1;
        }
        else {
            PyErr_Format(PyExc_TypeError, "got an unexpected or repeated keyword argument '%U'", key);
            return NULL;
        }
    }
    if (x == NULL) {
        PyErr_Format(PyExc_TypeError, "missing 1 required positional argument: '%s'", name);
    }
    return x;
}

/* ---------------------------------------------------------------------------------------------- Pipe */

typedef struct {
    PyObject_HEAD
    PyObject *pipe;     /* the Pipeline */
    PyObject *fallback; /* hot_pipe(pipe): the Python closure, for every case not handled here */
    PyObject *low;      /* clip bounds (simple == 2), or NULL */
    PyObject *high;
    npy_intp n;
    int typenum;
    long block;
    vectorcallfunc vectorcall;
} PipeObject;

static PyObject *
Pipe_vectorcall(PyObject *self_, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    PipeObject *self = (PipeObject *)self_;
    PyObject *x = signal_arg(args, nargsf, kwnames, "x", "obs");
    if (x == NULL) {
        return NULL;
    }
    long r = int_attr(self->pipe, s_r);
    if (r == -1 && PyErr_Occurred()) {
        return NULL;
    }
    long simple = int_attr(self->pipe, s_simple);
    if (simple == -1 && PyErr_Occurred()) {
        return NULL;
    }
    if (r == self->block || !(simple == 1 || (simple == 2 && self->low != NULL)) ||
        !plain(x, self->typenum, self->n)) {
        return PyObject_CallOneArg(self->fallback, x);
    }
    int failed;
    PyObject *row = row_at(self->pipe, r, &failed);
    if (failed) {
        return NULL;
    }
    if (row == NULL || !plain(row, self->typenum, self->n)) {
        Py_XDECREF(row);
        return PyObject_CallOneArg(self->fallback, x);
    }
    if (set_r(self->pipe, r + 1) < 0) {
        Py_DECREF(row);
        return NULL;
    }
    PyObject *out = add_rows(x, row, self->typenum, self->n, simple == 2 ? self->low : NULL, self->high);
    Py_DECREF(row);
    return out;
}

static PyObject *
Pipe_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"pipe", "fallback", "size", "dtype", "low", "high", "block", NULL};
    PyObject *pipe, *fallback, *dtype, *low, *high;
    Py_ssize_t size;
    long block;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOnOOOl", kwlist, &pipe, &fallback, &size, &dtype, &low, &high,
                                     &block)) {
        return NULL;
    }
    int typenum;
    if (typenum_of(dtype, &typenum) < 0) {
        return NULL;
    }
    if (!PyCallable_Check(fallback)) {
        PyErr_SetString(PyExc_TypeError, "`fallback` must be callable");
        return NULL;
    }
    if (!bounds_ok(low, high, typenum, size)) {
        PyErr_SetString(PyExc_ValueError, "`low` and `high` must both be None or 1-D arrays of `size` entries of `dtype`");
        return NULL;
    }
    PipeObject *self = (PipeObject *)type->tp_alloc(type, 0);
    if (self == NULL) {
        return NULL;
    }
    self->pipe = Py_NewRef(pipe);
    self->fallback = Py_NewRef(fallback);
    self->low = low == Py_None ? NULL : Py_NewRef(low);
    self->high = high == Py_None ? NULL : Py_NewRef(high);
    self->n = size;
    self->typenum = typenum;
    self->block = block;
    self->vectorcall = Pipe_vectorcall;
    return (PyObject *)self;
}

static int
Pipe_traverse(PipeObject *self, visitproc visit, void *arg)
{
    Py_VISIT(self->pipe);
    Py_VISIT(self->fallback);
    Py_VISIT(self->low);
    Py_VISIT(self->high);
    return 0;
}

static int
Pipe_clear(PipeObject *self)
{
    Py_CLEAR(self->pipe);
    Py_CLEAR(self->fallback);
    Py_CLEAR(self->low);
    Py_CLEAR(self->high);
    return 0;
}

static void
Pipe_dealloc(PipeObject *self)
{
    PyObject_GC_UnTrack(self);
    Pipe_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyObject *
Pipe_reduce(PipeObject *self, PyObject *Py_UNUSED(args))
{
    PyArray_Descr *descr = PyArray_DescrFromType(self->typenum);
    if (descr == NULL) {
        return NULL;
    }
    PyObject *out = Py_BuildValue("O(OOnNOOl)", (PyObject *)Py_TYPE(self), self->pipe, self->fallback, (Py_ssize_t)self->n,
                                  (PyObject *)descr, self->low ? self->low : Py_None, self->high ? self->high : Py_None,
                                  self->block);
    return out;
}

static PyMethodDef Pipe_methods[] = {
    {"__copy__", (PyCFunction)same_object, METH_NOARGS, PyDoc_STR("the object itself, as for a function")},
    {"__deepcopy__", (PyCFunction)same_object, METH_O, PyDoc_STR("the object itself, as for a function")},
    {"__reduce__", (PyCFunction)Pipe_reduce, METH_NOARGS,
     PyDoc_STR("made again from the pipeline and the fallback (what pickles the closure pickles this)")},
    {NULL},
};

static PyTypeObject PipeType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "noise_models._hot.Pipe",
    .tp_doc = PyDoc_STR("Pipe(pipe, fallback, size, dtype, low, high, block): hot_pipe(pipe) compiled; "
                        "called as (x) or (x, now)."),
    .tp_basicsize = sizeof(PipeObject),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_new = Pipe_new,
    .tp_traverse = (traverseproc)Pipe_traverse,
    .tp_clear = (inquiry)Pipe_clear,
    .tp_dealloc = (destructor)Pipe_dealloc,
    .tp_call = PyVectorcall_Call,
    .tp_vectorcall_offset = offsetof(PipeObject, vectorcall),
    .tp_methods = Pipe_methods,
};

/* ---------------------------------------------------------------------------------------------- NoisyLag */

typedef struct {
    PyObject_HEAD
    PyObject *pipe; /* the observation Pipeline (one additive stage, no clip) */
    PyObject *ring; /* the corruptor's ring of lag + 1 samples (a list) */
    Py_ssize_t lag;
    Py_ssize_t size;
    Py_ssize_t k; /* samples delivered this episode */
    npy_intp n;
    int typenum;
    long block;
    vectorcallfunc vectorcall;
} NoisyLagObject;

static PyObject *
NoisyLag_vectorcall(PyObject *self_, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    NoisyLagObject *self = (NoisyLagObject *)self_;
    PyObject *obs = signal_arg(args, nargsf, kwnames, "obs", NULL);
    if (obs == NULL) {
        return NULL;
    }
    long r = int_attr(self->pipe, s_r);
    if (r == -1 && PyErr_Occurred()) {
        return NULL;
    }
    PyObject *sample;
    if (r == self->block) {
        sample = PyObject_CallOneArg(self->pipe, obs); /* draws the next block */
    }
    else {
        if (set_r(self->pipe, r + 1) < 0) {
            return NULL;
        }
        int failed;
        PyObject *row = row_at(self->pipe, r, &failed);
        if (failed) {
            return NULL;
        }
        if (row == NULL) { /* as pipe.rows[r] would */
            PyObject *rows = PyObject_GetAttr(self->pipe, s_rows);
            if (rows == NULL) {
                return NULL;
            }
            PyObject *key = PyLong_FromLong(r);
            row = key == NULL ? NULL : PyObject_GetItem(rows, key);
            Py_XDECREF(key);
            Py_DECREF(rows);
            if (row == NULL) {
                return NULL;
            }
        }
        if (plain(obs, self->typenum, self->n) && plain(row, self->typenum, self->n)) {
            sample = add_rows(obs, row, self->typenum, self->n, NULL, NULL);
        }
        else {
            sample = PyNumber_Add(obs, row);
        }
        Py_DECREF(row);
    }
    if (sample == NULL) {
        return NULL;
    }
    Py_ssize_t k = self->k + 1;
    self->k = k;
    if (PyList_SetItem(self->ring, k % self->size, sample) < 0) { /* steals sample */
        return NULL;
    }
    Py_ssize_t j = ((k - self->lag) % self->size + self->size) % self->size;
    PyObject *out = PyList_GetItem(self->ring, j); /* checked: IndexError if the ring was shortened */
    if (out == NULL) {
        return NULL;
    }
    if (k > self->lag) {
        return Py_NewRef(out);
    }
    Py_INCREF(out);
    PyObject *copy = PyObject_CallMethodNoArgs(out, s_copy); /* the reset sample, delivered again */
    Py_DECREF(out);
    return copy;
}

static PyObject *
NoisyLag_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"pipe", "ring", "lag", "samples", "size", "dtype", "block", NULL};
    PyObject *pipe, *ring, *dtype;
    Py_ssize_t lag, samples, size;
    long block;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OO!nnnOl", kwlist, &pipe, &PyList_Type, &ring, &lag, &samples,
                                     &size, &dtype, &block)) {
        return NULL;
    }
    int typenum;
    if (typenum_of(dtype, &typenum) < 0) {
        return NULL;
    }
    if (lag < 0 || PyList_GET_SIZE(ring) != lag + 1) {
        PyErr_SetString(PyExc_ValueError, "`ring` must be a list of `lag` + 1 samples");
        return NULL;
    }
    NoisyLagObject *self = (NoisyLagObject *)type->tp_alloc(type, 0);
    if (self == NULL) {
        return NULL;
    }
    self->pipe = Py_NewRef(pipe);
    self->ring = Py_NewRef(ring);
    self->lag = lag;
    self->size = lag + 1;
    self->k = samples;
    self->n = size;
    self->typenum = typenum;
    self->block = block;
    self->vectorcall = NoisyLag_vectorcall;
    return (PyObject *)self;
}

static int
NoisyLag_traverse(NoisyLagObject *self, visitproc visit, void *arg)
{
    Py_VISIT(self->pipe);
    Py_VISIT(self->ring);
    return 0;
}

static int
NoisyLag_clear(NoisyLagObject *self)
{
    Py_CLEAR(self->pipe);
    Py_CLEAR(self->ring);
    return 0;
}

static void
NoisyLag_dealloc(NoisyLagObject *self)
{
    PyObject_GC_UnTrack(self);
    NoisyLag_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyObject *
NoisyLag_samples(NoisyLagObject *self, void *closure)
{
    return PyLong_FromSsize_t(self->k);
}

static PyGetSetDef NoisyLag_getset[] = {
    {"samples", (getter)NoisyLag_samples, NULL, PyDoc_STR("samples delivered this episode"), NULL},
    {NULL},
};

static PyObject *
NoisyLag_reduce(NoisyLagObject *self, PyObject *Py_UNUSED(args))
{
    PyArray_Descr *descr = PyArray_DescrFromType(self->typenum);
    if (descr == NULL) {
        return NULL;
    }
    return Py_BuildValue("O(OOnnnNl)", (PyObject *)Py_TYPE(self), self->pipe, self->ring, self->lag, self->k,
                         (Py_ssize_t)self->n, (PyObject *)descr, self->block);
}

static PyMethodDef NoisyLag_methods[] = {
    {"__copy__", (PyCFunction)same_object, METH_NOARGS, PyDoc_STR("the object itself, as for a function")},
    {"__deepcopy__", (PyCFunction)same_object, METH_O, PyDoc_STR("the object itself, as for a function")},
    {"__reduce__", (PyCFunction)NoisyLag_reduce, METH_NOARGS,
     PyDoc_STR("made again from the pipeline, the ring and the count (what pickles the closure pickles this)")},
    {NULL},
};

static PyTypeObject NoisyLagType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "noise_models._hot.NoisyLag",
    .tp_doc = PyDoc_STR("NoisyLag(pipe, ring, lag, samples, size, dtype, block): SignalCorruptor._hot_noisy_lag "
                        "compiled; called as (obs) or (obs, now)."),
    .tp_basicsize = sizeof(NoisyLagObject),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_new = NoisyLag_new,
    .tp_traverse = (traverseproc)NoisyLag_traverse,
    .tp_clear = (inquiry)NoisyLag_clear,
    .tp_dealloc = (destructor)NoisyLag_dealloc,
    .tp_call = PyVectorcall_Call,
    .tp_vectorcall_offset = offsetof(NoisyLagObject, vectorcall),
    .tp_getset = NoisyLag_getset,
    .tp_methods = NoisyLag_methods,
};

/* ---------------------------------------------------------------------------------------------- module */

static struct PyModuleDef hotmodule = {
    PyModuleDef_HEAD_INIT,
    .m_name = "noise_models._hot",
    .m_doc = PyDoc_STR("The compiled hot path of noise pipelines (see noise_models.compiled)."),
    .m_size = -1,
};

PyMODINIT_FUNC
PyInit__hot(void)
{
    import_array();
    s_r = PyUnicode_InternFromString("r");
    s_rows = PyUnicode_InternFromString("rows");
    s_simple = PyUnicode_InternFromString("simple");
    s_copy = PyUnicode_InternFromString("copy");
    if (s_r == NULL || s_rows == NULL || s_simple == NULL || s_copy == NULL) {
        return NULL;
    }
    if (PyType_Ready(&PipeType) < 0 || PyType_Ready(&NoisyLagType) < 0) {
        return NULL;
    }
    PyObject *m = PyModule_Create(&hotmodule);
    if (m == NULL) {
        return NULL;
    }
    if (PyModule_AddObjectRef(m, "Pipe", (PyObject *)&PipeType) < 0 ||
        PyModule_AddObjectRef(m, "NoisyLag", (PyObject *)&NoisyLagType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
