/* usb2rc.nodes._steady: the node step's steady path, compiled (usb2rc/nodes/steady.py).
 *
 * Python decides, this moves data. A node's step decides nothing new while it is steady:
 * every device present, known, reporting (not silent), its bad-report count as before, no
 * trim switch, no expected entry; and either the node waits in the neutral guard with every
 * waiting device's rest not begun (each guarded axis has moved since the plug, so no
 * "fixed" hint; its gate closed), or every device is armed and its gate open with nothing
 * held over. For such a node `step` does what `nodes.table._Node.step` does, with the same
 * values and the same state written back, and returns the NodeView; for anything else it
 * returns None before it has changed anything, and the Python step runs (the one home of
 * every decision), which then compiles the node's next plan (steady.plan_for).
 *
 * configure(classes, fields, limits): once, at import (steady.py): the NamedTuple classes
 * (DeviceView, NodeView, NodeFrame) and the indices of the fields read in records, views
 * and inputs, the constants of nodes.silence, nodes.guard and hid.reader.
 *
 * step(plan, records, now) -> NodeView | None
 *   plan     (layout, node, attached, devices, box) from steady.plan_for: `attached` the
 *            node's _Attached objects when it was made, `devices` one
 *            (binding, runs, kind, suffix) per device: the guard's runs as
 *            (low, high, text, fn, slot, centre, unsigned, terms): the wire values at
 *            rest, the axis's text, the binding's function of that slot (None: the
 *            binding does not feed it), whether it rests at the centre, whether it is
 *            unsigned, the function's terms where `scaling.linear_field` made it
 *            (computed here without calling it; None: it is called); the
 *            kind and the suffix of its reason ("guard X", " (X)"); `box` a one-item list
 *            holding the node's last view
 *   records  the reader records of this step, one per device
 *   now      the step's time
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define MAX_DEVICES 16 /* a node fed by more takes the Python step */

/* attribute names, interned once */
static PyObject *s_attached, *s_expected, *s_present, *s_silence_news, *s_bad_spells_seen,
    *s_silence, *s_silent_since, *s_source, *s_record, *s_armed, *s_rest, *s_gate,
    *s_device_id, *s_binding, *s_apply, *s_failsafe, *s_last_inputs, *s_values, *s_buttons,
    *s_reports, *s_kind, *s_streaming, *s_interval_s, *s_window, *s_seen_reports, *s_since,
    *s_moved_all_of, *s_moved, *s_first, *s_guard, *s_fixed, *s_run_since, *s_plugged, *s_waiting, *s_is_open,
    *s_held_hid, *s_held_groups, *s_counts_from, *s_last_serial, *s_stepped_reasons,
    *s_unsigned_slots, *s_handover, *s_failsafe_of;
static PyObject *str_on_change, *str_streaming, *str_join;

static PyObject *device_view_cls, *node_view_cls, *node_frame_cls;
/* field indices (configure) */
static Py_ssize_t r_state, r_reports, r_at, r_press_serial, r_refused, r_bad_spells, r_repeats;
static Py_ssize_t v_frame, v_devices, v_base_axes, v_base_unsigned;
static Py_ssize_t f_failsafe, f_node_id;
static Py_ssize_t d_inputs, d_live;
static Py_ssize_t i_axes, i_group1, i_group2, i_handover, i_low_battery;
static Py_ssize_t n_device_view, n_node_view, n_node_frame;
static long long bad_reports_limit, streaming_after;
static double min_silence_s, silence_intervals, rate_window_s, fixed_s, end_margin;
static int configured = 0;

/* A NamedTuple (a tuple subclass without a dict) from `n` borrowed items, as
 * tuple.__new__(cls, items) makes it. */
static PyObject *
make(PyObject *cls, Py_ssize_t n, PyObject *const *items)
{
    PyTypeObject *type = (PyTypeObject *)cls;
    PyObject *out = type->tp_alloc(type, n);
    if (out == NULL) {
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_INCREF(items[i]);
        PyTuple_SET_ITEM(out, i, items[i]);
    }
    return out;
}

static int
as_ll(PyObject *o, long long *out)
{
    long long v = PyLong_AsLongLong(o);
    if (v == -1 && PyErr_Occurred()) {
        return -1;
    }
    *out = v;
    return 0;
}

/* obj.name as long long; -1 with an exception on error */
static int
attr_ll(PyObject *obj, PyObject *name, long long *out)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    int rc = as_ll(v, out);
    Py_DECREF(v);
    return rc;
}

/* truth of obj.name: 1, 0, -1 on error */
static int
attr_true(PyObject *obj, PyObject *name)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    int rc = PyObject_IsTrue(v);
    Py_DECREF(v);
    return rc;
}

/* obj.name is `what`: 1, 0, -1 on error */
static int
attr_is(PyObject *obj, PyObject *name, PyObject *what)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    int rc = v == what;
    Py_DECREF(v);
    return rc;
}

static int
set_ll(PyObject *obj, PyObject *name, long long value)
{
    PyObject *v = PyLong_FromLongLong(value);
    if (v == NULL) {
        return -1;
    }
    int rc = PyObject_SetAttr(obj, name, v);
    Py_DECREF(v);
    return rc;
}

/* What nodes.silence.SilenceWatch.silent(record, now) would find and leave, computed
 * without writing it: `commit` writes it back once the whole node is found steady. */
typedef struct {
    int touched;        /* it would write its fields (a streaming check ran) */
    int silent;
    int streaming;
    double interval_s;
    PyObject *window;   /* new reference: the window it leaves */
    long long seen_reports;
} Silence;

static int
silence_check(PyObject *watch, PyObject *kind, PyObject *record, double now, Silence *out)
{
    out->touched = 0;
    out->silent = 0;
    out->window = NULL;
    PyObject *at_o = PyTuple_GET_ITEM(record, r_at);
    long long reports, refused, repeats;
    if (as_ll(PyTuple_GET_ITEM(record, r_reports), &reports) < 0
        || as_ll(PyTuple_GET_ITEM(record, r_refused), &refused) < 0
        || as_ll(PyTuple_GET_ITEM(record, r_repeats), &repeats) < 0) {
        return -1;
    }
    int on_change = PyUnicode_Compare(kind, str_on_change);
    if (on_change == -1 && PyErr_Occurred()) {
        return -1;
    }
    if (on_change == 0 || reports == 0 || at_o == Py_None || refused) {
        return 0;
    }
    double at = PyFloat_AsDouble(at_o);
    if (at == -1.0 && PyErr_Occurred()) {
        return -1;
    }
    out->touched = 1;
    int streaming = attr_true(watch, s_streaming);
    if (streaming < 0) {
        return -1;
    }
    if (!streaming) {
        int is_streaming = PyUnicode_Compare(kind, str_streaming);
        if (is_streaming == -1 && PyErr_Occurred()) {
            return -1;
        }
        streaming = is_streaming == 0 || repeats >= streaming_after;
    }
    out->streaming = streaming;
    PyObject *interval_o = PyObject_GetAttr(watch, s_interval_s);
    if (interval_o == NULL) {
        return -1;
    }
    out->interval_s = PyFloat_AsDouble(interval_o);
    Py_DECREF(interval_o);
    if (out->interval_s == -1.0 && PyErr_Occurred()) {
        return -1;
    }
    PyObject *window = PyObject_GetAttr(watch, s_window);
    if (window == NULL) {
        return -1;
    }
    int new_window = 0;
    if (window == Py_None) {
        new_window = 1;
    } else {
        double began;
        long long counted;
        if (!PyTuple_Check(window) || PyTuple_GET_SIZE(window) != 2) {
            Py_DECREF(window);
            PyErr_SetString(PyExc_TypeError, "SilenceWatch.window: (time, reports) expected");
            return -1;
        }
        began = PyFloat_AsDouble(PyTuple_GET_ITEM(window, 0));
        if ((began == -1.0 && PyErr_Occurred())
            || as_ll(PyTuple_GET_ITEM(window, 1), &counted) < 0) {
            Py_DECREF(window);
            return -1;
        }
        if (at - began >= rate_window_s && reports > counted) {
            out->interval_s = (at - began) / (double)(reports - counted);
            new_window = 1;
        }
    }
    if (new_window) {
        Py_DECREF(window);
        window = Py_BuildValue("(OO)", at_o, PyTuple_GET_ITEM(record, r_reports));
        if (window == NULL) {
            return -1;
        }
    }
    out->window = window;
    long long seen;
    if (attr_ll(watch, s_seen_reports, &seen) < 0) {
        Py_CLEAR(out->window);
        return -1;
    }
    int fresh = reports != seen;
    out->seen_reports = reports;
    double limit = silence_intervals * out->interval_s;
    if (!(limit > min_silence_s)) {
        limit = min_silence_s;
    }
    out->silent = streaming && !fresh && now - at > limit;
    return 0;
}

static int
silence_commit(PyObject *watch, PyObject *kind, const Silence *s)
{
    if (PyObject_SetAttr(watch, s_kind, kind) < 0) {
        return -1;
    }
    if (!s->touched) {
        return 0;
    }
    PyObject *interval = PyFloat_FromDouble(s->interval_s);
    if (interval == NULL) {
        return -1;
    }
    int rc = PyObject_SetAttr(watch, s_streaming, s->streaming ? Py_True : Py_False);
    if (rc == 0) {
        rc = PyObject_SetAttr(watch, s_interval_s, interval);
    }
    Py_DECREF(interval);
    if (rc == 0) {
        rc = PyObject_SetAttr(watch, s_window, s->window);
    }
    if (rc == 0) {
        rc = set_ll(watch, s_seen_reports, s->seen_reports);
    }
    return rc;
}

#define MAX_RUNS 16 /* guarded axes of one device (a node has ten slots) */

/* The wire value `scaling.linear_field` gives for the state's `fields` (a tuple), from its
 * terms (index, lo, hi, offset, invert) as `scaling.linear_terms` gives them: the same
 * integers, without calling the function. NULL without an exception when it cannot be
 * worked out here (no terms, a field out of range or too wide): the caller calls it. */
static PyObject *
linear_wire(PyObject *terms, PyObject *fields)
{
    long long index, lo, hi, offset, v;
    if (terms == Py_None || !PyTuple_Check(fields) || !PyTuple_Check(terms)
        || PyTuple_GET_SIZE(terms) != 5 || as_ll(PyTuple_GET_ITEM(terms, 0), &index) < 0
        || as_ll(PyTuple_GET_ITEM(terms, 1), &lo) < 0 || as_ll(PyTuple_GET_ITEM(terms, 2), &hi) < 0
        || as_ll(PyTuple_GET_ITEM(terms, 3), &offset) < 0 || index < 0
        || index >= PyTuple_GET_SIZE(fields) || as_ll(PyTuple_GET_ITEM(fields, index), &v) < 0) {
        PyErr_Clear();
        return NULL;
    }
    /* HID logical bounds are 32-bit: (v - lo) * 65535 stays far inside 64 bits */
    if (hi <= lo || lo < INT32_MIN || hi > INT32_MAX || v < INT32_MIN || v > INT32_MAX) {
        return NULL;
    }
    if (PyTuple_GET_ITEM(terms, 4) == Py_True) {
        v = lo + hi - v;
    }
    v = v < lo ? lo : v > hi ? hi : v;
    long long span = hi - lo, num = (v - lo) * 65535, q = num / span, r = num % span;
    if (2 * r > span || (2 * r == span && (q & 1))) { /* halves to even, as round_div */
        q++;
    }
    return PyLong_FromLongLong(q - offset);
}

/* Each guarded axis's wire value in the record's state, as binding.guarded_axes gives it
 * (NULL: the binding does not feed the slot), new references in `values`; the texts of
 * those not at rest (guard.NeutralGuard.waiting_for, no trims) as a new tuple. */
static PyObject *
guard_values(PyObject *runs, PyObject *state, PyObject **values)
{
    PyObject *fields = PyObject_GetAttr(state, s_values);
    if (fields == NULL) {
        return NULL;
    }
    PyObject *buttons = PyObject_GetAttr(state, s_buttons);
    if (buttons == NULL) {
        Py_DECREF(fields);
        return NULL;
    }
    PyObject *texts = PyList_New(0);
    Py_ssize_t n = PyTuple_GET_SIZE(runs);
    for (Py_ssize_t k = 0; texts != NULL && k < n; k++) {
        PyObject *run = PyTuple_GET_ITEM(runs, k);
        PyObject *fn = PyTuple_GET_ITEM(run, 3);
        if (fn == Py_None) {
            continue; /* the binding sends nothing on this slot: never outside */
        }
        PyObject *wire = linear_wire(PyTuple_GET_ITEM(run, 7), fields);
        if (wire == NULL && !PyErr_Occurred()) {
            PyObject *args[2] = {fields, buttons};
            wire = PyObject_Vectorcall(fn, args, 2, NULL);
        }
        long long value, first, last;
        int failed = wire == NULL || as_ll(wire, &value) < 0
                     || as_ll(PyTuple_GET_ITEM(run, 0), &first) < 0
                     || as_ll(PyTuple_GET_ITEM(run, 1), &last) < 0;
        values[k] = wire;
        if (failed || (!(first <= value && value <= last)
                       && PyList_Append(texts, PyTuple_GET_ITEM(run, 2)) < 0)) {
            Py_CLEAR(texts);
        }
    }
    Py_DECREF(fields);
    Py_DECREF(buttons);
    if (texts == NULL) {
        return NULL;
    }
    PyObject *out = PyList_AsTuple(texts);
    Py_DECREF(texts);
    return out;
}

typedef struct {
    PyObject *attached;  /* borrowed (the plan holds it) */
    PyObject *binding;   /* borrowed */
    PyObject *record;    /* borrowed (records) */
    PyObject *gate;      /* new */
    PyObject *rest;      /* new, waiting only */
    PyObject *inputs;    /* new */
    PyObject *waiting;   /* new, waiting only: the axes it waits for */
    PyObject *kind;      /* new (its `reports:`) */
    PyObject *guard;     /* new, waiting only */
    PyObject *moves;     /* new, waiting only: slots that moved at this step */
    int all_moved;       /* waiting only: every guarded axis has moved, from this step */
    int live;
    Silence silence;
} Device;

static void
device_clear(Device *d)
{
    Py_CLEAR(d->gate);
    Py_CLEAR(d->rest);
    Py_CLEAR(d->inputs);
    Py_CLEAR(d->waiting);
    Py_CLEAR(d->silence.window);
    Py_CLEAR(d->kind);
    Py_CLEAR(d->guard);
    Py_CLEAR(d->moves);
}

/* RestWatch.check of a device whose rest has not begun (nodes/guard.py), without writing
 * anything: what it waits for (d->waiting), the moves to note, whether every guarded axis
 * has moved. 0 when the Python step must decide: every guarded axis
 * rests (a rest begins), or an unmoved centre axis sits at an end (the "fixed" hint). */
static int
rest_check(PyObject *runs, PyObject *state, double now, Device *d)
{
    Py_ssize_t n = PyTuple_GET_SIZE(runs);
    if (n > MAX_RUNS) {
        return 0;
    }
    PyObject *values[MAX_RUNS] = {NULL};
    int rc = 1;
    PyObject *first = NULL, *moved = NULL;
    d->waiting = guard_values(runs, state, values);
    if (d->waiting == NULL) {
        rc = -1;
        goto done;
    }
    if (PyTuple_GET_SIZE(d->waiting) == 0) {
        rc = 0; /* every guarded axis rests: a rest begins (the Python step) */
        goto done;
    }
    int all_moved = attr_is(d->rest, s_moved_all_of, d->guard);
    if (all_moved < 0) {
        rc = -1;
        goto done;
    }
    d->all_moved = 1;
    if (all_moved) {
        goto fixed; /* `moved` only grows: nothing to note */
    }
    moved = PyObject_GetAttr(d->rest, s_moved);
    first = PyObject_GetAttr(d->rest, s_first);
    d->moves = PySet_New(NULL);
    if (moved == NULL || first == NULL || d->moves == NULL) {
        rc = -1;
        goto done;
    }
    if (!PyDict_Check(first) || !PyAnySet_Check(moved)) {
        rc = 0;
        goto done;
    }
    /* RestWatch._note_moves (noting a record twice notes nothing new: the same values
     * against the same first values) */
    for (Py_ssize_t k = 0; k < n; k++) {
        PyObject *slot = PyTuple_GET_ITEM(PyTuple_GET_ITEM(runs, k), 4);
        int has = PySet_Contains(moved, slot);
        if (has < 0) {
            rc = -1;
            goto done;
        }
        if (values[k] != NULL && !has) {
            PyObject *seen = PyDict_GetItemWithError(first, slot);
            if (seen == NULL) {
                /* its first value is noted by the first step that reads it: the Python one */
                rc = PyErr_Occurred() ? -1 : 0;
                goto done;
            }
            int same = PyObject_RichCompareBool(values[k], seen, Py_EQ);
            if (same < 0 || (!same && PySet_Add(d->moves, slot) < 0)) {
                rc = -1;
                goto done;
            }
            has = !same;
        }
        d->all_moved = d->all_moved && has;
    }
fixed:
    /* guard.RestWatch._not_at_rest: a centre axis unmoved since the plug and at an end of
     * its travel, FIXED_S after the plug while not every axis has moved */
    if (!d->all_moved) {
        PyObject *plugged_o = PyObject_GetAttr(d->rest, s_plugged);
        double plugged = plugged_o ? PyFloat_AsDouble(plugged_o) : -1.0;
        Py_XDECREF(plugged_o);
        if (plugged_o == NULL || (plugged == -1.0 && PyErr_Occurred())) {
            rc = -1;
            goto done;
        }
        if (!(now - plugged < fixed_s)) {
            for (Py_ssize_t k = 0; k < n; k++) {
                PyObject *run = PyTuple_GET_ITEM(runs, k);
                PyObject *slot = PyTuple_GET_ITEM(run, 4);
                if (values[k] == NULL || PyTuple_GET_ITEM(run, 5) != Py_True) {
                    continue; /* not fed, or not a centre axis */
                }
                int has = PySet_Contains(moved, slot);
                int now_moved = has == 1 ? 1 : PySet_Contains(d->moves, slot);
                long long wire;
                if (has < 0 || now_moved < 0 || as_ll(values[k], &wire) < 0) {
                    rc = -1;
                    goto done;
                }
                double offset = PyTuple_GET_ITEM(run, 6) == Py_True ? 0.0 : -32768.0;
                double unit = ((double)wire - offset) * 2.0 / 65535.0 - 1.0;
                if (!now_moved && fabs(unit) >= 1.0 - end_margin) {
                    rc = 0; /* the hint: the Python step says it */
                    goto done;
                }
            }
        }
    }
done:
    for (Py_ssize_t k = 0; k < n; k++) {
        Py_XDECREF(values[k]);
    }
    Py_XDECREF(first);
    Py_XDECREF(moved);
    return rc;
}

/* `binding.failsafe(last)`: its memo's value while `last` is the one it was worked out for
 * (as the method answers it), else the method's answer. */
static PyObject *
binding_failsafe(PyObject *binding, PyObject *last)
{
    PyObject *memo = PyObject_GetAttr(binding, s_failsafe_of);
    if (memo == NULL) {
        return NULL;
    }
    if (PyTuple_Check(memo) && PyTuple_GET_SIZE(memo) == 2 && PyTuple_GET_ITEM(memo, 0) == last) {
        PyObject *inputs = Py_NewRef(PyTuple_GET_ITEM(memo, 1));
        Py_DECREF(memo);
        return inputs;
    }
    Py_DECREF(memo);
    return PyObject_CallMethodOneArg(binding, s_failsafe, last);
}

/* 1: the device is steady (filled in), 0: not (the Python step decides), -1: error */
static int
device_check(PyObject *dplan, PyObject *attached, PyObject *record, PyObject *prev_device,
             double now, Device *d)
{
    d->attached = attached;
    d->binding = PyTuple_GET_ITEM(dplan, 0);
    d->record = record;
    int rc;
    if ((rc = attr_is(attached, s_binding, d->binding)) != 1) {
        return rc; /* a reload gave it another binding */
    }
    if ((rc = attr_true(attached, s_present)) != 1 || (rc = attr_true(attached, s_silence_news)) != 0) {
        return rc < 0 ? -1 : 0;
    }
    long long seen, spells;
    if (attr_ll(attached, s_bad_spells_seen, &seen) < 0
        || as_ll(PyTuple_GET_ITEM(record, r_bad_spells), &spells) < 0) {
        return -1;
    }
    if (seen != spells) {
        return 0; /* a run of bad reports began: the Python step holds the values */
    }
    if ((rc = attr_is(attached, s_silent_since, Py_None)) != 1) {
        return rc;
    }
    /* `a.source.record` is the one stepped: the reasons read it */
    PyObject *source = PyObject_GetAttr(attached, s_source);
    if (source == NULL) {
        return -1;
    }
    rc = attr_is(source, s_record, record);
    Py_DECREF(source);
    if (rc != 1) {
        return rc;
    }
    d->kind = PyObject_GetAttr(d->binding, s_reports);
    if (d->kind == NULL) {
        return -1;
    }
    PyObject *watch = PyObject_GetAttr(attached, s_silence);
    if (watch == NULL) {
        return -1;
    }
    rc = silence_check(watch, d->kind, record, now, &d->silence);
    Py_DECREF(watch);
    if (rc < 0) {
        return -1;
    }
    if (d->silence.silent) {
        return 0;
    }
    long long reports, refused;
    if (as_ll(PyTuple_GET_ITEM(record, r_reports), &reports) < 0
        || as_ll(PyTuple_GET_ITEM(record, r_refused), &refused) < 0) {
        return -1;
    }
    if (reports <= 0 || refused >= bad_reports_limit) {
        return 0; /* not known */
    }
    int armed = attr_true(attached, s_armed);
    if (armed < 0) {
        return -1;
    }
    d->gate = PyObject_GetAttr(attached, s_gate);
    if (d->gate == NULL) {
        return -1;
    }
    PyObject *state = PyTuple_GET_ITEM(record, r_state);
    int was_live = PyObject_IsTrue(PyTuple_GET_ITEM(prev_device, d_live));
    if (was_live < 0) {
        return -1;
    }
    if (armed) {
        if (!was_live) {
            return 0;
        }
        d->live = 1;
        d->inputs = PyObject_CallMethodOneArg(d->binding, s_apply, state);
        return d->inputs == NULL ? -1 : 1;
    }
    if (was_live) {
        return 0;
    }
    d->live = 0;
    d->rest = PyObject_GetAttr(attached, s_rest);
    if (d->rest == NULL) {
        return -1;
    }
    d->guard = PyObject_GetAttr(d->binding, s_guard);
    if (d->guard == NULL) {
        return -1;
    }
    if ((rc = attr_is(d->rest, s_since, Py_None)) != 1
        || (rc = attr_is(d->rest, s_run_since, Py_None)) != 1
        || (rc = attr_is(d->rest, s_plugged, Py_None)) != 0) {
        return rc < 0 ? -1 : 0; /* a rest began, or the first step: the Python step's */
    }
    rc = rest_check(PyTuple_GET_ITEM(dplan, 1), state, now, d);
    if (rc != 1) {
        return rc;
    }
    PyObject *last = PyObject_GetAttr(attached, s_last_inputs);
    if (last == NULL) {
        return -1;
    }
    d->inputs = binding_failsafe(d->binding, last);
    Py_DECREF(last);
    return d->inputs == NULL ? -1 : 1;
}

/* The node's gates as the step needs them: closed while it waits, open with nothing held
 * over while live. 1 / 0 / -1 */
static int
gate_ready(PyObject *gate, int node_live)
{
    int open = attr_true(gate, s_is_open);
    if (open < 0 || open != node_live) {
        return open < 0 ? -1 : 0;
    }
    if (!node_live) {
        return 1;
    }
    int rc = attr_true(gate, s_held_hid);
    if (rc != 0) {
        return rc < 0 ? -1 : 0;
    }
    PyObject *held = PyObject_GetAttr(gate, s_held_groups);
    if (held == NULL) {
        return -1;
    }
    long long g1 = 1, g2 = 1;
    if (PyTuple_Check(held) && PyTuple_GET_SIZE(held) == 2) {
        if (as_ll(PyTuple_GET_ITEM(held, 0), &g1) < 0 || as_ll(PyTuple_GET_ITEM(held, 1), &g2) < 0) {
            Py_DECREF(held);
            return -1;
        }
    }
    Py_DECREF(held);
    return g1 == 0 && g2 == 0;
}

/* nodes.step.compose, for a node without expected entries (its base axes are the view's) */
static PyObject *
compose(PyObject *prev, PyObject *node_id, int failsafe, Device *devs, Py_ssize_t n)
{
    PyObject *base = PyTuple_GET_ITEM(prev, v_base_axes);
    Py_ssize_t slots = PyTuple_GET_SIZE(base);
    PyObject *axes = PyTuple_New(slots);
    PyObject *g1 = PyLong_FromLong(0), *g2 = PyLong_FromLong(0);
    PyObject *unsigned_ = PyTuple_GET_ITEM(prev, v_base_unsigned);
    Py_INCREF(unsigned_);
    PyObject *handover = Py_None, *low = Py_False;
    PyObject *zero = PyLong_FromLong(0);
    PyObject *frame = NULL, *pressed = NULL, *empty = PyTuple_New(0);
    Py_INCREF(handover);
    Py_INCREF(low);
    if (axes == NULL || g1 == NULL || g2 == NULL || zero == NULL || empty == NULL) {
        goto done;
    }
    for (Py_ssize_t k = 0; k < slots; k++) {
        PyObject *v = PyTuple_GET_ITEM(base, k);
        Py_INCREF(v);
        PyTuple_SET_ITEM(axes, k, v);
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *inputs = devs[i].inputs;
        PyObject *dev_axes = PyTuple_GET_ITEM(inputs, i_axes);
        Py_ssize_t m = PyTuple_GET_SIZE(dev_axes);
        for (Py_ssize_t k = 0; k < m && k < slots; k++) {
            PyObject *v = PyTuple_GET_ITEM(dev_axes, k);
            if (v != Py_None) {
                PyObject *old = PyTuple_GET_ITEM(axes, k);
                Py_INCREF(v);
                PyTuple_SET_ITEM(axes, k, v);
                Py_DECREF(old);
            }
        }
        PyObject *u = PyObject_GetAttr(devs[i].binding, s_unsigned_slots);
        if (u == NULL) {
            goto done;
        }
        Py_SETREF(g1, PyNumber_Or(g1, PyTuple_GET_ITEM(inputs, i_group1)));
        Py_SETREF(g2, PyNumber_Or(g2, PyTuple_GET_ITEM(inputs, i_group2)));
        Py_SETREF(unsigned_, PyNumber_Or(unsigned_, u));
        Py_DECREF(u);
        if (g1 == NULL || g2 == NULL || unsigned_ == NULL) {
            goto done;
        }
        int ho = PyObject_IsTrue(PyTuple_GET_ITEM(inputs, i_handover));
        if (ho < 0) {
            goto done;
        }
        if (ho) {
            PyObject *h = PyObject_GetAttr(devs[i].binding, s_handover);
            if (h == NULL) {
                goto done;
            }
            Py_SETREF(handover, h);
        }
        int low_now = PyObject_IsTrue(low);
        if (low_now < 0) {
            goto done;
        }
        if (!low_now) { /* `low or inputs.low_battery`: the latter's own value */
            Py_INCREF(PyTuple_GET_ITEM(inputs, i_low_battery));
            Py_SETREF(low, PyTuple_GET_ITEM(inputs, i_low_battery));
        }
    }
    /* table._pressed: what is not held over; a live steady node holds nothing over, so all
     * of it (a node in failsafe acts on no press) */
    pressed = failsafe ? PyTuple_Pack(2, zero, zero) : PyTuple_Pack(2, g1, g2);
    if (pressed == NULL) {
        goto done;
    }
    PyObject *items[11] = {node_id, failsafe ? Py_True : Py_False, axes, g1, g2, unsigned_,
                           handover, low, empty, pressed, empty};
    frame = make(node_frame_cls, n_node_frame, items);
done:
    Py_XDECREF(axes);
    Py_XDECREF(g1);
    Py_XDECREF(g2);
    Py_XDECREF(unsigned_);
    Py_XDECREF(handover);
    Py_XDECREF(low);
    Py_XDECREF(zero);
    Py_XDECREF(pressed);
    Py_XDECREF(empty);
    return frame;
}

/* The waiting node's reasons (table._Node.reasons, every device waiting in the guard or
 * live): (waiting_for, stepped_reasons), new references. */
static int
reasons_of(PyObject *dplans, Device *devs, Py_ssize_t n, PyObject **waiting_for,
           PyObject **stepped)
{
    PyObject *texts = PyList_New(0), *pairs = PyList_New(0);
    if (texts == NULL || pairs == NULL) {
        goto fail;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        if (devs[i].live) {
            continue;
        }
        PyObject *dplan = PyTuple_GET_ITEM(dplans, i);
        PyObject *joined = PyUnicode_Join(str_join, devs[i].waiting);
        PyObject *text = joined ? PyUnicode_Concat(joined, PyTuple_GET_ITEM(dplan, 3)) : NULL;
        Py_XDECREF(joined);
        PyObject *pair = text ? PyTuple_Pack(2, PyTuple_GET_ITEM(dplan, 2), text) : NULL;
        int rc = pair == NULL || PyList_Append(texts, text) < 0 || PyList_Append(pairs, pair) < 0;
        Py_XDECREF(text);
        Py_XDECREF(pair);
        if (rc) {
            goto fail;
        }
    }
    *waiting_for = PyList_AsTuple(texts);
    Py_DECREF(texts);
    if (*waiting_for == NULL) {
        Py_DECREF(pairs);
        return -1;
    }
    *stepped = pairs;
    return 0;
fail:
    Py_XDECREF(texts);
    Py_XDECREF(pairs);
    return -1;
}

/* What RestWatch.check writes besides the record and the waiting texts: the moves noted,
 * `moved_all_of` once every axis has moved, `fixed` (none, when steady). */
static int
rest_commit(Device *d)
{
    if (PyObject_SetAttr(d->rest, s_fixed, Py_False) < 0) {
        return -1;
    }
    if (d->moves == NULL) {
        return 0; /* every axis had moved already */
    }
    PyObject *moved = PyObject_GetAttr(d->rest, s_moved);
    PyObject *slot;
    int rc = moved == NULL ? -1 : 0;
    PyObject *it = rc == 0 ? PyObject_GetIter(d->moves) : NULL;
    if (rc == 0 && it == NULL) {
        rc = -1;
    }
    while (rc == 0 && (slot = PyIter_Next(it)) != NULL) {
        rc = PySet_Add(moved, slot);
        Py_DECREF(slot);
    }
    if (rc == 0 && PyErr_Occurred()) {
        rc = -1;
    }
    Py_XDECREF(it);
    Py_XDECREF(moved);
    if (rc == 0 && d->all_moved) {
        rc = PyObject_SetAttr(d->rest, s_moved_all_of, d->guard);
    }
    return rc;
}

/* The state the Python step writes, written back: the silence watches; a waiting device's
 * rest (the record taken) and what it waits for; a closed gate's marks. */
static int
commit(Device *devs, Py_ssize_t n, int node_live)
{
    for (Py_ssize_t i = 0; i < n; i++) {
        Device *d = &devs[i];
        PyObject *watch = PyObject_GetAttr(d->attached, s_silence);
        if (watch == NULL) {
            return -1;
        }
        int rc = silence_commit(watch, d->kind, &d->silence);
        Py_DECREF(watch);
        if (rc < 0) {
            return -1;
        }
        if (!d->live && rest_commit(d) < 0) {
            return -1;
        }
        if (!d->live) {
            if (PyObject_SetAttr(d->rest, s_record, d->record) < 0
                || PyObject_SetAttr(d->rest, s_reports, PyTuple_GET_ITEM(d->record, r_reports)) < 0
                || PyObject_SetAttr(d->rest, s_waiting, d->waiting) < 0
                || PyObject_SetAttr(d->attached, s_waiting, d->waiting) < 0) {
                return -1;
            }
        }
        if (!node_live) { /* presses.PressGate.step of a node in failsafe */
            PyObject *serial = PyTuple_GET_ITEM(d->record, r_press_serial);
            PyObject *state = PyTuple_GET_ITEM(d->record, r_state);
            PyObject *buttons = PyObject_GetAttr(state, s_buttons);
            PyObject *held = PyTuple_Pack(2, PyTuple_GET_ITEM(d->inputs, i_group1),
                                          PyTuple_GET_ITEM(d->inputs, i_group2));
            int failed = buttons == NULL || held == NULL
                         || PyObject_SetAttr(d->gate, s_counts_from, serial) < 0
                         || PyObject_SetAttr(d->gate, s_last_serial, serial) < 0
                         || PyObject_SetAttr(d->gate, s_held_hid, buttons) < 0
                         || PyObject_SetAttr(d->gate, s_held_groups, held) < 0;
            Py_XDECREF(buttons);
            Py_XDECREF(held);
            if (failed) {
                return -1;
            }
        }
    }
    return 0;
}

static PyObject *
steady_step(PyObject *self, PyObject *args)
{
    PyObject *plan, *records;
    double now;
    if (!PyArg_ParseTuple(args, "O!O!d", &PyTuple_Type, &plan, &PyTuple_Type, &records, &now)) {
        return NULL;
    }
    if (!configured) {
        PyErr_SetString(PyExc_RuntimeError, "_steady.configure() was not called");
        return NULL;
    }
    if (PyTuple_GET_SIZE(plan) != 5) {
        PyErr_SetString(PyExc_ValueError, "plan: (layout, node, attached, devices, box)");
        return NULL;
    }
    PyObject *node = PyTuple_GET_ITEM(plan, 1);
    PyObject *attached = PyTuple_GET_ITEM(plan, 2);
    PyObject *dplans = PyTuple_GET_ITEM(plan, 3);
    PyObject *box = PyTuple_GET_ITEM(plan, 4);
    Py_ssize_t n = PyTuple_GET_SIZE(attached);
    if (n == 0 || n > MAX_DEVICES || PyTuple_GET_SIZE(records) != n
        || PyTuple_GET_SIZE(dplans) != n || !PyList_Check(box) || PyList_GET_SIZE(box) != 1) {
        Py_RETURN_NONE;
    }
    /* the node's devices are the plan's, in its order, and it expects no entry */
    PyObject *now_attached = PyObject_GetAttr(node, s_attached);
    if (now_attached == NULL) {
        return NULL;
    }
    int same = PyList_Check(now_attached) && PyList_GET_SIZE(now_attached) == n;
    for (Py_ssize_t i = 0; same && i < n; i++) {
        same = PyList_GET_ITEM(now_attached, i) == PyTuple_GET_ITEM(attached, i);
    }
    Py_DECREF(now_attached);
    int expects = attr_true(node, s_expected);
    if (expects < 0) {
        return NULL;
    }
    if (!same || expects) {
        Py_RETURN_NONE;
    }
    PyObject *prev = PyList_GET_ITEM(box, 0);
    if (!PyTuple_Check(prev) || PyTuple_GET_SIZE(prev) != n_node_view) {
        Py_RETURN_NONE;
    }
    PyObject *prev_frame = PyTuple_GET_ITEM(prev, v_frame);
    PyObject *prev_devices = PyTuple_GET_ITEM(prev, v_devices);
    if (PyTuple_GET_SIZE(prev_devices) != n) {
        Py_RETURN_NONE;
    }
    int failsafe = PyObject_IsTrue(PyTuple_GET_ITEM(prev_frame, f_failsafe));
    if (failsafe < 0) {
        return NULL;
    }

    Py_INCREF(prev); /* held while Python code runs (an axis function, `apply`) */
    Device devs[MAX_DEVICES];
    memset(devs, 0, sizeof(devs));
    PyObject *views[MAX_DEVICES] = {NULL};
    PyObject *result = NULL, *frame = NULL, *devices = NULL, *waiting_for = NULL;
    PyObject *stepped = NULL;
    int steady = 1, waiting_any = 0;
    for (Py_ssize_t i = 0; steady == 1 && i < n; i++) {
        steady = device_check(PyTuple_GET_ITEM(dplans, i), PyTuple_GET_ITEM(attached, i),
                              PyTuple_GET_ITEM(records, i), PyTuple_GET_ITEM(prev_devices, i),
                              now, &devs[i]);
        if (steady == 1 && !devs[i].live) {
            waiting_any = 1;
        }
    }
    if (steady == 1 && waiting_any != failsafe) {
        steady = 0; /* the node arms or disarms: the Python step */
    }
    for (Py_ssize_t i = 0; steady == 1 && i < n; i++) {
        steady = gate_ready(devs[i].gate, !failsafe);
    }
    if (steady != 1) {
        goto done;
    }
    /* the views, as table._Attached._view makes them (gate marks as the last step left them) */
    PyObject *empty = PyTuple_New(0);
    if (empty == NULL) {
        steady = -1;
        goto done;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Device *d = &devs[i];
        PyObject *id = PyObject_GetAttr(d->attached, s_device_id);
        PyObject *held = PyObject_GetAttr(d->gate, s_held_groups);
        PyObject *counts = PyObject_GetAttr(d->gate, s_counts_from);
        if (id != NULL && held != NULL && counts != NULL) {
            PyObject *items[9] = {id, d->binding, d->inputs, d->live ? Py_True : Py_False,
                                  Py_True, d->record, empty, held, counts};
            views[i] = make(device_view_cls, n_device_view, items);
        }
        Py_XDECREF(id);
        Py_XDECREF(held);
        Py_XDECREF(counts);
        if (views[i] == NULL) {
            Py_DECREF(empty);
            steady = -1;
            goto done;
        }
    }
    Py_DECREF(empty);
    /* the frame: the last one while no device's inputs changed (a waiting node's) */
    int inputs_same = 1;
    for (Py_ssize_t i = 0; inputs_same && i < n; i++) {
        inputs_same = devs[i].inputs == PyTuple_GET_ITEM(PyTuple_GET_ITEM(prev_devices, i), d_inputs);
    }
    if (inputs_same) {
        frame = prev_frame;
        Py_INCREF(frame);
    } else {
        frame = compose(prev, PyTuple_GET_ITEM(prev_frame, f_node_id), failsafe, devs, n);
        if (frame == NULL) {
            steady = -1;
            goto done;
        }
    }
    if (failsafe) {
        if (reasons_of(dplans, devs, n, &waiting_for, &stepped) < 0) {
            steady = -1;
            goto done;
        }
    } else {
        waiting_for = PyTuple_New(0);
        stepped = PyList_New(0);
        if (waiting_for == NULL || stepped == NULL) {
            steady = -1;
            goto done;
        }
    }
    devices = PyTuple_New(n);
    if (devices == NULL) {
        steady = -1;
        goto done;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyTuple_SET_ITEM(devices, i, views[i]);
        views[i] = NULL;
    }
    if (commit(devs, n, !failsafe) < 0
        || PyObject_SetAttr(node, s_stepped_reasons, stepped) < 0) {
        steady = -1;
        goto done;
    }
    PyObject *empty_overrides = PyTuple_New(0);
    if (empty_overrides == NULL) {
        steady = -1;
        goto done;
    }
    PyObject *items[6] = {frame, devices, PyTuple_GET_ITEM(prev, v_base_axes),
                          PyTuple_GET_ITEM(prev, v_base_unsigned), waiting_for, empty_overrides};
    result = make(node_view_cls, n_node_view, items);
    Py_DECREF(empty_overrides);
    if (result == NULL) {
        steady = -1;
        goto done;
    }
    Py_INCREF(result);
    PyList_SET_ITEM(box, 0, result); /* steals; the list's reference to the last view: */
    Py_DECREF(prev);
done:
    for (Py_ssize_t i = 0; i < n; i++) {
        device_clear(&devs[i]);
        Py_XDECREF(views[i]);
    }
    Py_XDECREF(frame);
    Py_XDECREF(devices);
    Py_XDECREF(waiting_for);
    Py_XDECREF(stepped);
    Py_DECREF(prev);
    if (steady < 0) {
        Py_XDECREF(result);
        return NULL;
    }
    if (steady == 0) {
        Py_RETURN_NONE;
    }
    return result;
}

static int
index_of(PyObject *fields, const char *key, Py_ssize_t *out)
{
    PyObject *v = PyDict_GetItemString(fields, key); /* borrowed */
    if (v == NULL) {
        PyErr_Format(PyExc_KeyError, "configure: no field index %s", key);
        return -1;
    }
    *out = PyLong_AsSsize_t(v);
    return *out == -1 && PyErr_Occurred() ? -1 : 0;
}

static int
limit_of(PyObject *limits, const char *key, double *out)
{
    PyObject *v = PyDict_GetItemString(limits, key);
    if (v == NULL) {
        PyErr_Format(PyExc_KeyError, "configure: no limit %s", key);
        return -1;
    }
    *out = PyFloat_AsDouble(v);
    return *out == -1.0 && PyErr_Occurred() ? -1 : 0;
}

static PyObject *
steady_configure(PyObject *self, PyObject *args)
{
    PyObject *dv, *nv, *nf, *fields, *limits;
    if (!PyArg_ParseTuple(args, "(OOO)O!O!", &dv, &nv, &nf, &PyDict_Type, &fields,
                          &PyDict_Type, &limits)) {
        return NULL;
    }
    PyObject *classes[3] = {dv, nv, nf};
    for (int k = 0; k < 3; k++) {
        if (!PyType_Check(classes[k]) || !PyType_IsSubtype((PyTypeObject *)classes[k], &PyTuple_Type)) {
            PyErr_SetString(PyExc_TypeError, "configure: NamedTuple classes expected");
            return NULL;
        }
    }
    double limit, after;
    if (index_of(fields, "record.state", &r_state) < 0
        || index_of(fields, "record.reports", &r_reports) < 0
        || index_of(fields, "record.at", &r_at) < 0
        || index_of(fields, "record.press_serial", &r_press_serial) < 0
        || index_of(fields, "record.refused_in_a_row", &r_refused) < 0
        || index_of(fields, "record.bad_spells", &r_bad_spells) < 0
        || index_of(fields, "record.repeats", &r_repeats) < 0
        || index_of(fields, "view.frame", &v_frame) < 0
        || index_of(fields, "view.devices", &v_devices) < 0
        || index_of(fields, "view.base_axes", &v_base_axes) < 0
        || index_of(fields, "view.base_unsigned", &v_base_unsigned) < 0
        || index_of(fields, "frame.node_id", &f_node_id) < 0
        || index_of(fields, "frame.failsafe", &f_failsafe) < 0
        || index_of(fields, "device.inputs", &d_inputs) < 0
        || index_of(fields, "device.live", &d_live) < 0
        || index_of(fields, "inputs.axes", &i_axes) < 0
        || index_of(fields, "inputs.group1", &i_group1) < 0
        || index_of(fields, "inputs.group2", &i_group2) < 0
        || index_of(fields, "inputs.handover", &i_handover) < 0
        || index_of(fields, "inputs.low_battery", &i_low_battery) < 0
        || index_of(fields, "sizes.device", &n_device_view) < 0
        || index_of(fields, "sizes.view", &n_node_view) < 0
        || index_of(fields, "sizes.frame", &n_node_frame) < 0
        || limit_of(limits, "bad_reports_limit", &limit) < 0
        || limit_of(limits, "streaming_after", &after) < 0
        || limit_of(limits, "min_silence_s", &min_silence_s) < 0
        || limit_of(limits, "silence_intervals", &silence_intervals) < 0
        || limit_of(limits, "rate_window_s", &rate_window_s) < 0
        || limit_of(limits, "fixed_s", &fixed_s) < 0
        || limit_of(limits, "end_margin", &end_margin) < 0) {
        return NULL;
    }
    if (n_device_view != 9 || n_node_view != 6 || n_node_frame != 11) {
        PyErr_SetString(PyExc_ValueError, "configure: the views' fields are not the ones built here");
        return NULL;
    }
    bad_reports_limit = (long long)limit;
    streaming_after = (long long)after;
    Py_INCREF(dv);
    Py_XSETREF(device_view_cls, dv);
    Py_INCREF(nv);
    Py_XSETREF(node_view_cls, nv);
    Py_INCREF(nf);
    Py_XSETREF(node_frame_cls, nf);
    configured = 1;
    Py_RETURN_NONE;
}

static PyObject *
steady_linear_wire(PyObject *module, PyObject *args)
{
    (void)module;
    PyObject *terms, *fields;
    if (!PyArg_ParseTuple(args, "OO", &terms, &fields)) {
        return NULL;
    }
    PyObject *wire = linear_wire(terms, fields);
    if (wire == NULL && !PyErr_Occurred()) {
        Py_RETURN_NONE;
    }
    return wire;
}

static PyMethodDef module_methods[] = {
    {"configure", steady_configure, METH_VARARGS,
     "configure((DeviceView, NodeView, NodeFrame), fields, limits)"},
    {"step", steady_step, METH_VARARGS,
     "step(plan, records, now) -> NodeView, or None: not steady (the Python step decides)"},
    {"linear_wire", steady_linear_wire, METH_VARARGS,
     "linear_wire(terms, fields) -> the wire value the step works out for a linear axis, or "
     "None: it calls the axis's function (tests hold it to scaling.linear_field)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "_steady",
    .m_doc = "The node step's steady path, compiled.",
    .m_size = -1,
    .m_methods = module_methods,
};

#define INTERN(var, text)                                  \
    if ((var = PyUnicode_InternFromString(text)) == NULL) { \
        return NULL;                                       \
    }

PyMODINIT_FUNC
PyInit__steady(void)
{
    INTERN(s_attached, "attached");
    INTERN(s_expected, "expected");
    INTERN(s_present, "present");
    INTERN(s_silence_news, "silence_news");
    INTERN(s_bad_spells_seen, "bad_spells_seen");
    INTERN(s_silence, "silence");
    INTERN(s_silent_since, "silent_since");
    INTERN(s_source, "source");
    INTERN(s_record, "record");
    INTERN(s_armed, "armed");
    INTERN(s_rest, "rest");
    INTERN(s_gate, "gate");
    INTERN(s_device_id, "device_id");
    INTERN(s_binding, "binding");
    INTERN(s_apply, "apply");
    INTERN(s_failsafe, "failsafe");
    INTERN(s_last_inputs, "last_inputs");
    INTERN(s_values, "values");
    INTERN(s_buttons, "buttons");
    INTERN(s_reports, "reports");
    INTERN(s_kind, "kind");
    INTERN(s_streaming, "streaming");
    INTERN(s_interval_s, "interval_s");
    INTERN(s_window, "window");
    INTERN(s_seen_reports, "seen_reports");
    INTERN(s_since, "since");
    INTERN(s_moved_all_of, "moved_all_of");
    INTERN(s_moved, "moved");
    INTERN(s_first, "first");
    INTERN(s_guard, "guard");
    INTERN(s_fixed, "fixed");
    INTERN(s_run_since, "run_since");
    INTERN(s_plugged, "plugged");
    INTERN(s_waiting, "waiting");
    INTERN(s_is_open, "is_open");
    INTERN(s_held_hid, "held_hid");
    INTERN(s_held_groups, "held_groups");
    INTERN(s_counts_from, "counts_from");
    INTERN(s_last_serial, "last_serial");
    INTERN(s_stepped_reasons, "stepped_reasons");
    INTERN(s_unsigned_slots, "unsigned_slots");
    INTERN(s_handover, "handover");
    INTERN(s_failsafe_of, "_failsafe_of");
    INTERN(str_on_change, "on_change");
    INTERN(str_streaming, "streaming");
    INTERN(str_join, ", ");
    return PyModule_Create(&module);
}
