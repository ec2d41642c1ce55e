/* The compiled hot step of RandomizeAndCorrupt (sim2real.wrappers._hotstep): the step closure
 * RandomizeAndCorrupt._make_hot_step builds for an episode, as one callable type, so that the layer's per-step work
 * (checks, the action ring, the report) costs no Python bytecode. Optional: sim2real.wrappers.fused uses it when the
 * extension is built and noise_models.compiled is enabled, and the closure otherwise; tests/test_compiled.py pins the
 * two bitwise, and every branch here is a line of that closure, in its order:
 *
 *     if type(action) is not ndarray: action = asarray(action, dtype=dtype)
 *     if action.shape != shape: raise ValueError(wrong_action_shape(action.shape, shape))
 *     sent = act(action)
 *     ring None:  clock._passed = 0; clock._in_step = True; ... = env_step(sent); clock._in_step = False
 *     else:       k = wrapper._actions_sent; wrapper._actions_sent = k + 1
 *                 ring[k % size] = sent.copy() if sent is action else sent; ... = env_step(ring[(k + 1) % size])
 *     if (info and ("diverged" in info or "sim2real" in info)) or (diverged is not None and diverged()):
 *         return step_end(obs, reward, terminated, truncated, info, True)
 *     wrapper._last_obs = obs
 *     report = template.copy()
 *     report["params"] = merged.copy() if (randomizer.current_params is phys and corruptor.current_params is
 *                                          signals) else wrapper._params().copy()
 *     info["sim2real"] = report
 *     return observe(obs, 0), reward, terminated, truncated, info
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


static PyObject *s_passed, *s_in_step, *s_actions_sent, *s_last_obs, *s_current_params, *s_params, *s_copy,
    *s_diverged, *s_sim2real, *s_dtype, *s_shape, *s_params_method, *zero;

typedef struct {
    PyObject_HEAD
    PyObject *wrapper, *clock, *env_step, *ring, *act, *observe, *template_, *dtype, *randomizer, *corruptor;
    PyObject *phys, *signals, *merged, *step_end, *diverged, *asarray, *wrong_shape;
    Py_ssize_t size; /* the ring's */
    int ndim;
    npy_intp shape[NPY_MAXDIMS];
    vectorcallfunc vectorcall;
} HotStepObject;

static PyObject *
copy_of(PyObject *d)
{
    if (PyDict_CheckExact(d)) {
        return PyDict_Copy(d);
    }
    return PyObject_CallMethodNoArgs(d, s_copy);
}

/* Raises ValueError(wrong_action_shape(action.shape, shape)). */
static PyObject *
wrong_shape(HotStepObject *self, PyObject *action)
{
    PyObject *got = PyObject_GetAttr(action, s_shape);
    if (got == NULL) {
        return NULL;
    }
    PyObject *expected = PyTuple_New(self->ndim);
    if (expected == NULL) {
        Py_DECREF(got);
        return NULL;
    }
    for (int i = 0; i < self->ndim; i++) {
        PyObject *v = PyLong_FromSsize_t(self->shape[i]);
        if (v == NULL) {
            Py_DECREF(got);
            Py_DECREF(expected);
            return NULL;
        }
        PyTuple_SET_ITEM(expected, i, v);
    }
    PyObject *msg = PyObject_CallFunctionObjArgs(self->wrong_shape, got, expected, NULL);
    Py_DECREF(got);
    Py_DECREF(expected);
    if (msg != NULL) {
        PyErr_SetObject(PyExc_ValueError, msg);
        Py_DECREF(msg);
    }
    return NULL;
}

/* Unpacks the env's step result into five new references, with Python's errors for the wrong length. */
static int
unpack5(PyObject *result, PyObject **out)
{
    if (Py_TYPE(result)->tp_iter == NULL && !PySequence_Check(result)) {
        PyErr_Format(PyExc_TypeError, "cannot unpack non-iterable %.200s object", Py_TYPE(result)->tp_name);
        return -1;
    }
    PyObject *seq = PySequence_Fast(result, "cannot unpack non-iterable object");
    if (seq == NULL) {
        return -1;
    }
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n != 5) {
        if (n > 5) {
            PyErr_SetString(PyExc_ValueError, "too many values to unpack (expected 5)");
        }
        else {
            PyErr_Format(PyExc_ValueError, "not enough values to unpack (expected 5, got %zd)", n);
        }
        Py_DECREF(seq);
        return -1;
    }
    PyObject **items = PySequence_Fast_ITEMS(seq);
    for (int i = 0; i < 5; i++) {
        out[i] = Py_NewRef(items[i]);
    }
    Py_DECREF(seq);
    return 0;
}

static int
is_attr(PyObject *obj, PyObject *name, PyObject *expected)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    int same = v == expected;
    Py_DECREF(v);
    return same;
}

static PyObject *
HotStep_vectorcall(PyObject *self_, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    HotStepObject *self = (HotStepObject *)self_;
    Py_ssize_t nargs = PyVectorcall_NARGS(nargsf);
    Py_ssize_t nkw = kwnames == NULL ? 0 : PyTuple_GET_SIZE(kwnames);
    if (nargs + nkw != 1 || (nkw == 1 && PyUnicode_CompareWithASCIIString(PyTuple_GET_ITEM(kwnames, 0), "action"))) {
        if (nkw == 1 && nargs == 0) {
            PyErr_Format(PyExc_TypeError, "step() got an unexpected keyword argument '%U'", PyTuple_GET_ITEM(kwnames, 0));
        }
        else {
            PyErr_Format(PyExc_TypeError, "step() takes 1 argument, `action` (%zd given)", nargs + nkw);
        }
        return NULL;
    }
    PyObject *action;
    if (Py_TYPE(args[0]) != &PyArray_Type) {
        PyObject *kw = PyDict_New();
        if (kw == NULL || PyDict_SetItem(kw, s_dtype, self->dtype) < 0) {
            Py_XDECREF(kw);
            return NULL;
        }
        PyObject *pos = PyTuple_Pack(1, args[0]);
        action = pos == NULL ? NULL : PyObject_Call(self->asarray, pos, kw);
        Py_XDECREF(pos);
        Py_DECREF(kw);
        if (action == NULL) {
            return NULL;
        }
    }
    else {
        action = Py_NewRef(args[0]);
    }
    PyObject *sent = NULL, *result = NULL, *report = NULL, *params = NULL, *obs_out = NULL;
    PyObject *parts[5] = {NULL, NULL, NULL, NULL, NULL};
    PyObject *ret = NULL;
    if (!PyArray_Check(action)) {
        PyErr_SetString(PyExc_TypeError, "np.asarray did not return an ndarray");
        goto done;
    }
    {
        PyArrayObject *a = (PyArrayObject *)action;
        int same = PyArray_NDIM(a) == self->ndim;
        for (int i = 0; same && i < self->ndim; i++) {
            same = PyArray_DIM(a, i) == self->shape[i];
        }
        if (!same) {
            wrong_shape(self, action);
            goto done;
        }
    }
    sent = PyObject_CallOneArg(self->act, action);
    if (sent == NULL) {
        goto done;
    }
    if (self->ring == Py_None) {
        if (PyObject_SetAttr(self->clock, s_passed, zero) < 0 || PyObject_SetAttr(self->clock, s_in_step, Py_True) < 0) {
            goto done;
        }
        result = PyObject_CallOneArg(self->env_step, sent);
        if (result == NULL || unpack5(result, parts) < 0) {
            goto done;
        }
        if (PyObject_SetAttr(self->clock, s_in_step, Py_False) < 0) {
            goto done;
        }
    }
    else {
        PyObject *kobj = PyObject_GetAttr(self->wrapper, s_actions_sent);
        if (kobj == NULL) {
            goto done;
        }
        Py_ssize_t k = PyLong_AsSsize_t(kobj);
        Py_DECREF(kobj);
        if (k == -1 && PyErr_Occurred()) {
            goto done;
        }
        PyObject *next = PyLong_FromSsize_t(k + 1);
        if (next == NULL) {
            goto done;
        }
        int rc = PyObject_SetAttr(self->wrapper, s_actions_sent, next);
        Py_DECREF(next);
        if (rc < 0) {
            goto done;
        }
        PyObject *kept = sent == action ? PyObject_CallMethodNoArgs(sent, s_copy) : Py_NewRef(sent);
        if (kept == NULL) {
            goto done;
        }
        Py_ssize_t size = self->size;
        Py_ssize_t slot = ((k % size) + size) % size;
        if (PyList_SetItem(self->ring, slot, kept) < 0) { /* steals kept */
            goto done;
        }
        Py_ssize_t due = (((k + 1) % size) + size) % size;
        PyObject *command = PyList_GetItem(self->ring, due); /* checked: IndexError if the ring was shortened */
        if (command == NULL) {
            goto done;
        }
        Py_INCREF(command); /* held through the call, as the caller's frame holds its argument */
        result = PyObject_CallOneArg(self->env_step, command);
        Py_DECREF(command);
        if (result == NULL || unpack5(result, parts) < 0) {
            goto done;
        }
    }
    PyObject *obs = parts[0], *info = parts[4];
    {
        int flagged = PyObject_IsTrue(info);
        if (flagged < 0) {
            goto done;
        }
        if (flagged) {
            flagged = PySequence_Contains(info, s_diverged);
            if (flagged == 0) {
                flagged = PySequence_Contains(info, s_sim2real);
            }
            if (flagged < 0) {
                goto done;
            }
        }
        if (!flagged && self->diverged != Py_None) {
            PyObject *d = PyObject_CallNoArgs(self->diverged);
            if (d == NULL) {
                goto done;
            }
            flagged = PyObject_IsTrue(d);
            Py_DECREF(d);
            if (flagged < 0) {
                goto done;
            }
        }
        if (flagged) {
            ret = PyObject_CallFunctionObjArgs(self->step_end, parts[0], parts[1], parts[2], parts[3], parts[4],
                                               Py_True, NULL);
            goto done;
        }
    }
    if (PyObject_SetAttr(self->wrapper, s_last_obs, obs) < 0) {
        goto done;
    }
    report = copy_of(self->template_);
    if (report == NULL) {
        goto done;
    }
    {
        int same = is_attr(self->randomizer, s_current_params, self->phys);
        if (same == 1) {
            same = is_attr(self->corruptor, s_current_params, self->signals);
        }
        if (same < 0) {
            goto done;
        }
        if (same) {
            params = copy_of(self->merged);
        }
        else {
            PyObject *fresh = PyObject_CallMethodNoArgs(self->wrapper, s_params_method);
            if (fresh == NULL) {
                goto done;
            }
            params = copy_of(fresh);
            Py_DECREF(fresh);
        }
    }
    if (params == NULL || PyObject_SetItem(report, s_params, params) < 0 ||
        PyObject_SetItem(info, s_sim2real, report) < 0) {
        goto done;
    }
    {
        PyObject *oargs[2] = {obs, zero};
        obs_out = PyObject_Vectorcall(self->observe, oargs, 2, NULL);
    }
    if (obs_out == NULL) {
        goto done;
    }
    ret = PyTuple_Pack(5, obs_out, parts[1], parts[2], parts[3], parts[4]);
done:
    Py_DECREF(action);
    Py_XDECREF(sent);
    Py_XDECREF(result);
    Py_XDECREF(report);
    Py_XDECREF(params);
    Py_XDECREF(obs_out);
    for (int i = 0; i < 5; i++) {
        Py_XDECREF(parts[i]);
    }
    return ret;
}

static PyObject *
HotStep_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"wrapper", "clock", "env_step", "ring", "act", "observe", "template", "shape",
                             "dtype", "randomizer", "corruptor", "phys", "signals", "merged", "step_end",
                             "diverged", "asarray", "wrong_shape", NULL};
    PyObject *o[18];
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOOOO!OOOOOOOOOO", kwlist, &o[0], &o[1], &o[2], &o[3], &o[4],
                                     &o[5], &o[6], &PyTuple_Type, &o[7], &o[8], &o[9], &o[10], &o[11], &o[12], &o[13],
                                     &o[14], &o[15], &o[16], &o[17])) {
        return NULL;
    }
    PyObject *ring = o[3], *shape = o[7];
    if (ring != Py_None && (!PyList_CheckExact(ring) || PyList_GET_SIZE(ring) == 0)) {
        PyErr_SetString(PyExc_TypeError, "`ring` must be None or a non-empty list");
        return NULL;
    }
    Py_ssize_t ndim = PyTuple_GET_SIZE(shape);
    if (ndim > NPY_MAXDIMS) {
        PyErr_SetString(PyExc_ValueError, "`shape` has too many dimensions");
        return NULL;
    }
    HotStepObject *self = (HotStepObject *)type->tp_alloc(type, 0);
    if (self == NULL) {
        return NULL;
    }
    self->ndim = (int)ndim;
    for (Py_ssize_t i = 0; i < ndim; i++) {
        self->shape[i] = PyLong_AsSsize_t(PyTuple_GET_ITEM(shape, i));
        if (self->shape[i] == -1 && PyErr_Occurred()) {
            Py_DECREF(self);
            return NULL;
        }
    }
    self->wrapper = Py_NewRef(o[0]);
    self->clock = Py_NewRef(o[1]);
    self->env_step = Py_NewRef(o[2]);
    self->ring = Py_NewRef(ring);
    self->act = Py_NewRef(o[4]);
    self->observe = Py_NewRef(o[5]);
    self->template_ = Py_NewRef(o[6]);
    self->dtype = Py_NewRef(o[8]);
    self->randomizer = Py_NewRef(o[9]);
    self->corruptor = Py_NewRef(o[10]);
    self->phys = Py_NewRef(o[11]);
    self->signals = Py_NewRef(o[12]);
    self->merged = Py_NewRef(o[13]);
    self->step_end = Py_NewRef(o[14]);
    self->diverged = Py_NewRef(o[15]);
    self->asarray = Py_NewRef(o[16]);
    self->wrong_shape = Py_NewRef(o[17]);
    self->size = ring == Py_None ? 0 : PyList_GET_SIZE(ring);
    self->vectorcall = HotStep_vectorcall;
    return (PyObject *)self;
}

#define HOTSTEP_FIELDS(X)                                                                                              \
    X(wrapper) X(clock) X(env_step) X(ring) X(act) X(observe) X(template_) X(dtype) X(randomizer) X(corruptor)       \
        X(phys) X(signals) X(merged) X(step_end) X(diverged) X(asarray) X(wrong_shape)

static int
HotStep_traverse(HotStepObject *self, visitproc visit, void *arg)
{
#define VISIT(f) Py_VISIT(self->f);
    HOTSTEP_FIELDS(VISIT)
#undef VISIT
    return 0;
}

static int
HotStep_clear(HotStepObject *self)
{
#define CLEAR(f) Py_CLEAR(self->f);
    HOTSTEP_FIELDS(CLEAR)
#undef CLEAR
    return 0;
}

static void
HotStep_dealloc(HotStepObject *self)
{
    PyObject_GC_UnTrack(self);
    HotStep_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* inspect.signature(env.step): (action), as the closure's. */
static PyObject *
HotStep_signature(HotStepObject *self, void *closure)
{
    PyObject *inspect = PyImport_ImportModule("inspect");
    if (inspect == NULL) {
        return NULL;
    }
    PyObject *out = NULL, *param = NULL, *params = NULL;
    PyObject *Parameter = PyObject_GetAttrString(inspect, "Parameter");
    PyObject *Signature = PyObject_GetAttrString(inspect, "Signature");
    PyObject *kind = Parameter == NULL ? NULL : PyObject_GetAttrString(Parameter, "POSITIONAL_OR_KEYWORD");
    if (kind != NULL) {
        param = PyObject_CallFunction(Parameter, "sO", "action", kind);
    }
    if (param != NULL) {
        params = PyList_New(1);
        if (params != NULL) {
            PyList_SET_ITEM(params, 0, Py_NewRef(param));
            out = PyObject_CallOneArg(Signature, params);
        }
    }
    Py_XDECREF(params);
    Py_XDECREF(param);
    Py_XDECREF(kind);
    Py_XDECREF(Signature);
    Py_XDECREF(Parameter);
    Py_DECREF(inspect);
    return out;
}

static PyGetSetDef HotStep_getset[] = {
    {"__signature__", (getter)HotStep_signature, NULL, PyDoc_STR("(action), as the Python step's"), NULL},
    {NULL},
};

static PyObject *
HotStep_reduce(HotStepObject *self, PyObject *Py_UNUSED(args))
{
    PyObject *shape = PyTuple_New(self->ndim);
    if (shape == NULL) {
        return NULL;
    }
    for (int i = 0; i < self->ndim; i++) {
        PyObject *v = PyLong_FromSsize_t(self->shape[i]);
        if (v == NULL) {
            Py_DECREF(shape);
            return NULL;
        }
        PyTuple_SET_ITEM(shape, i, v);
    }
    return Py_BuildValue("O(OOOOOOONOOOOOOOOOO)", (PyObject *)Py_TYPE(self), self->wrapper, self->clock, self->env_step,
                         self->ring, self->act, self->observe, self->template_, shape, self->dtype, self->randomizer,
                         self->corruptor, self->phys, self->signals, self->merged, self->step_end, self->diverged,
                         self->asarray, self->wrong_shape);
}

static PyMethodDef HotStep_methods[] = {
    {"__copy__", (PyCFunction)same_object, METH_NOARGS, PyDoc_STR("the object itself, as for a function")},
    {"__deepcopy__", (PyCFunction)same_object, METH_O, PyDoc_STR("the object itself, as for a function")},
    {"__reduce__", (PyCFunction)HotStep_reduce, METH_NOARGS,
     PyDoc_STR("made again from what it was made of (what pickles the closure pickles this)")},
    {NULL},
};

static PyTypeObject HotStepType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "sim2real.wrappers._hotstep.HotStep",
    .tp_doc = PyDoc_STR("RandomizeAndCorrupt's hot step for one episode, compiled (see _make_hot_step)."),
    .tp_basicsize = sizeof(HotStepObject),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_new = HotStep_new,
    .tp_traverse = (traverseproc)HotStep_traverse,
    .tp_clear = (inquiry)HotStep_clear,
    .tp_dealloc = (destructor)HotStep_dealloc,
    .tp_call = PyVectorcall_Call,
    .tp_vectorcall_offset = offsetof(HotStepObject, vectorcall),
    .tp_methods = HotStep_methods,
    .tp_getset = HotStep_getset,
};

static struct PyModuleDef hotstepmodule = {
    PyModuleDef_HEAD_INIT,
    .m_name = "sim2real.wrappers._hotstep",
    .m_doc = PyDoc_STR("RandomizeAndCorrupt's compiled hot step (see noise_models.compiled)."),
    .m_size = -1,
};

PyMODINIT_FUNC
PyInit__hotstep(void)
{
    import_array();
#define INTERN(var, text)                                                                                              \
    if ((var = PyUnicode_InternFromString(text)) == NULL)                                                              \
        return NULL;
    INTERN(s_passed, "_passed")
    INTERN(s_in_step, "_in_step")
    INTERN(s_actions_sent, "_actions_sent")
    INTERN(s_last_obs, "_last_obs")
    INTERN(s_current_params, "current_params")
    INTERN(s_params, "params")
    INTERN(s_copy, "copy")
    INTERN(s_diverged, "diverged")
    INTERN(s_sim2real, "sim2real")
    INTERN(s_dtype, "dtype")
    INTERN(s_shape, "shape")
    INTERN(s_params_method, "_params")
#undef INTERN
    if ((zero = PyLong_FromLong(0)) == NULL) {
        return NULL;
    }
    if (PyType_Ready(&HotStepType) < 0) {
        return NULL;
    }
    PyObject *m = PyModule_Create(&hotstepmodule);
    if (m == NULL) {
        return NULL;
    }
    if (PyModule_AddObjectRef(m, "HotStep", (PyObject *)&HotStepType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
