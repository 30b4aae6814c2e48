/* bench_cold.py --touch: what one call from Python costs on a cold host, by what it touches.
 *
 * Three functions, each called once after a pause: `nothing` (the call alone), `fields`
 * (sixteen fields of one small C struct read and written: compact state) and `attrs` (a
 * name looked up on each of several Python objects in turn: state kept in Python objects,
 * as the compiled pull and step keep it). Built by bench_cold.py with the interpreter's own
 * headers. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

typedef struct {
    PyObject_HEAD
    double values[8];
    long counts[8];
} Compact;

static PyTypeObject CompactType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "cold_touch.Compact",
    .tp_basicsize = sizeof(Compact),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
};

static PyObject *
nothing(PyObject *module, PyObject *arg)
{
    Py_RETURN_NONE;
}

static PyObject *
fields(PyObject *module, PyObject *arg)
{
    if (!PyObject_TypeCheck(arg, &CompactType)) {
        PyErr_SetString(PyExc_TypeError, "fields(Compact)");
        return NULL;
    }
    Compact *c = (Compact *)arg;
    double sum = 0.0;
    for (int i = 0; i < 8; i++) {
        sum += c->values[i];
        c->counts[i] += 1;
    }
    return PyFloat_FromDouble(sum);
}

/* attrs((objects...), (names...)): names[i] looked up on objects[i % len(objects)] */
static PyObject *
attrs(PyObject *module, PyObject *args)
{
    PyObject *objects, *names;
    if (!PyArg_ParseTuple(args, "O!O!", &PyTuple_Type, &objects, &PyTuple_Type, &names)) {
        return NULL;
    }
    Py_ssize_t n = PyTuple_GET_SIZE(objects);
    if (n == 0) {
        PyErr_SetString(PyExc_ValueError, "attrs: no object");
        return NULL;
    }
    double sum = 0.0;
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(names); i++) {
        PyObject *value = PyObject_GetAttr(PyTuple_GET_ITEM(objects, i % n),
                                           PyTuple_GET_ITEM(names, i));
        if (value == NULL) {
            return NULL;
        }
        sum += PyFloat_Check(value) ? PyFloat_AS_DOUBLE(value) : 0.0;
        Py_DECREF(value);
    }
    return PyFloat_FromDouble(sum);
}

static PyMethodDef methods[] = {
    {"nothing", nothing, METH_O, "the call alone"},
    {"fields", fields, METH_O, "sixteen fields of a Compact"},
    {"attrs", attrs, METH_VARARGS, "names looked up on Python objects"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, .m_name = "cold_touch", .m_size = -1, .m_methods = methods,
};

PyMODINIT_FUNC
PyInit_cold_touch(void)
{
    if (PyType_Ready(&CompactType) < 0) {
        return NULL;
    }
    PyObject *m = PyModule_Create(&module);
    if (m != NULL && PyModule_AddObjectRef(m, "Compact", (PyObject *)&CompactType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
