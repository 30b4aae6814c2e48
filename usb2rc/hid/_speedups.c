/* usb2rc.hid._speedups: the HID stage's optional C loops.
 *
 * Where this module is not built (no C compiler or Python headers at install) or is
 * switched off (USB2RC_PURE_PYTHON), the Python code it speeds up runs instead, with the
 * same results: tests/test_speedups.py holds each function to its Python twin.
 *
 * Plan.drain: a batch of HID input reports drained in one loop, the compiled form of
 * `descriptor.ReportDecoder.feed_batch` for the common layouts: every value field at most
 * 32 bits, every button at most bit 63, no Button-page array.
 *
 * Plan(uses_ids, reports): reports is a sequence of
 *     (report_id, length, keep, fields, buttons)
 *   report_id  the first byte of the report (ignored without report IDs: one entry)
 *   length     bytes the report must have, the ID byte included
 *   keep       the button mask bits this report does not own (uint64)
 *   fields     ((value_index, bit_offset, bit_size, signed), ...) bit_offset from byte 0
 *   buttons    ((bit_offset, bit_size, count, first_button), ...) as descriptor.ButtonField
 *
 * Plan.drain(batch, values, mask, edges) -> (accepted, refused, mask, changes)
 *   batch     list of bytes, oldest first
 *   values    the decoder's list of values: each report ID's last valid report is decoded
 *             into it (a report sets every field of its ID, so earlier ones never show)
 *   mask      the button mask before the batch
 *   edges     False: changes are the masks after each report that changed the mask (as
 *             feed_batch's on_buttons); True: the buttons each such report pressed, for
 *             every report that pressed one (the reader's press log)
 *
 * parse_events(lines): hid-recorder `E:` lines as hid-recorder writes them, the compiled
 * form of `recording._events_as_written`: (times, reports), or None when any line is not
 * exactly `E: <digits[.digits]> <length> <length two-digit hex bytes, one space apart>`
 * followed by whitespace only. None is no verdict: the Python parse then decides (it takes
 * a few more spellings, and names a bad line).
 *
 * parse_packed(text): the complete lines of a block of a recording's text (those that end in
 * '\n'), each as parse_events takes it, without making a string per line, packed in one Events
 * object (the reports back to back, their times as doubles: no object per event until it is
 * taken): (events, end, lines), `end` the index after the last '\n' and `lines` their
 * count; None when the text is not ASCII, holds no complete line, or one of them is not as
 * written. Events.pairs(): (times, reports) as lists. Events.schedule(start, speed, floor):
 * when each is due, start + t / speed, never before the one before it nor before `floor` (a
 * running maximum from `floor`); the last due. Events.take(now, limit): the reports due at
 * `now`, at most `limit`, from the first not taken. `recording.EventList` is its Python twin.
 *
 * pull(reader, device, now, limit, kept, bad_limit): a pulled reader's pull of a replay
 * device in one call (below): the reports due taken from the packed batches in place,
 * drained as Plan.drain drains them, counted and published as the reader's Python pull
 * does, on the reader's, decoder's and device's own fields. tests/test_compiled_pull.py
 * holds it to the Python pull.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

typedef struct {
    Py_ssize_t index;
    Py_ssize_t offset;
    int size;
    int is_signed;
} Field;

typedef struct {
    Py_ssize_t offset;
    int size;
    int count;
    int first;
} Button;

typedef struct {
    int report_id;
    Py_ssize_t length;
    uint64_t keep;
    Field *fields;
    Py_ssize_t n_fields;
    Button *buttons;
    Py_ssize_t n_buttons;
} Report;

static PyTypeObject PlanType;

typedef struct {
    PyObject_HEAD
    int uses_ids;
    Report *reports;
    Py_ssize_t n_reports;
    int by_id[256]; /* report ID -> index in reports, -1: unknown */
} PlanObject;

/* `n` (1..64) bits of `p` from bit `off`, little-endian as int.from_bytes(r, "little");
 * bits past the end read 0 (never happens for a report of the plan's length). */
static uint64_t
get_bits(const unsigned char *p, Py_ssize_t len, Py_ssize_t off, int n)
{
    uint64_t v = 0;
    int got = 0;
    Py_ssize_t byte = off >> 3;
    int shift = (int)(off & 7);
    while (got < n) {
        uint64_t b = byte < len ? (uint64_t)(p[byte] >> shift) : 0;
        v |= b << got;
        got += 8 - shift;
        byte++;
        shift = 0;
    }
    return n < 64 ? v & ((UINT64_C(1) << n) - 1) : v;
}

static uint64_t
report_buttons(const Report *r, const unsigned char *p, Py_ssize_t len)
{
    uint64_t b = 0;
    for (Py_ssize_t i = 0; i < r->n_buttons; i++) {
        const Button *k = &r->buttons[i];
        if (k->size == 1) {
            b |= get_bits(p, len, k->offset, k->count) << (k->first - 1);
        } else if (get_bits(p, len, k->offset, k->size)) {
            b |= UINT64_C(1) << (k->first - 1);
        }
    }
    return b;
}

static int
decode_values(const Report *r, const unsigned char *p, Py_ssize_t len, PyObject *values)
{
    for (Py_ssize_t i = 0; i < r->n_fields; i++) {
        const Field *f = &r->fields[i];
        int64_t v = (int64_t)get_bits(p, len, f->offset, f->size);
        if (f->is_signed) {
            int64_t sign = (int64_t)1 << (f->size - 1);
            v = (v ^ sign) - sign;
        }
        PyObject *item = PyLong_FromLongLong(v);
        if (item == NULL) {
            return -1;
        }
        if (PyList_SetItem(values, f->index, item) < 0) { /* steals item */
            return -1;
        }
    }
    return 0;
}

static void
plan_free_reports(PlanObject *self)
{
    for (Py_ssize_t i = 0; i < self->n_reports; i++) {
        PyMem_Free(self->reports[i].fields);
        PyMem_Free(self->reports[i].buttons);
    }
    PyMem_Free(self->reports);
    self->reports = NULL;
    self->n_reports = 0;
}

static void
plan_dealloc(PlanObject *self)
{
    plan_free_reports(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* One (index, offset, size, signed) tuple into a Field; -1 with an exception. */
static int
parse_field(PyObject *item, void *out)
{
    Field *f = out;
    if (!PyArg_ParseTuple(item, "nnip", &f->index, &f->offset, &f->size, &f->is_signed)) {
        return -1;
    }
    if (f->size < 1 || f->size > 32 || f->index < 0 || f->offset < 0) {
        PyErr_SetString(PyExc_ValueError, "a field must be 1..32 bits");
        return -1;
    }
    f->is_signed = f->is_signed && f->size > 1;
    return 0;
}

/* One (offset, size, count, first) tuple into a Button; -1 with an exception. */
static int
parse_button(PyObject *item, void *out)
{
    Button *k = out;
    if (!PyArg_ParseTuple(item, "niii", &k->offset, &k->size, &k->count, &k->first)) {
        return -1;
    }
    int top = k->size == 1 ? k->first - 1 + k->count : k->first;
    if (k->offset < 0 || k->size < 1 || k->size > 64 || k->count < 1 || k->count > 64
        || k->first < 1 || top > 64) {
        PyErr_SetString(PyExc_ValueError, "a button must be within bits 0..63");
        return -1;
    }
    return 0;
}

/* Every item of `seq` parsed into a new array of `size`-byte elements (*count of them);
 * NULL with an exception. */
static void *
parse_all(PyObject *seq, size_t size, int (*parse)(PyObject *, void *), Py_ssize_t *count)
{
    PyObject *fast = PySequence_Fast(seq, "a plan's fields and buttons are sequences");
    if (fast == NULL) {
        return NULL;
    }
    *count = PySequence_Fast_GET_SIZE(fast);
    char *items = PyMem_Calloc(*count ? (size_t)*count : 1, size);
    if (items == NULL) {
        Py_DECREF(fast);
        PyErr_NoMemory();
        return NULL;
    }
    for (Py_ssize_t i = 0; i < *count; i++) {
        if (parse(PySequence_Fast_GET_ITEM(fast, i), items + (size_t)i * size) < 0) {
            PyMem_Free(items);
            Py_DECREF(fast);
            return NULL;
        }
    }
    Py_DECREF(fast);
    return items;
}

static int
plan_init(PlanObject *self, PyObject *args, PyObject *kwds)
{
    int uses_ids;
    PyObject *reports;
    static char *kwlist[] = {"uses_ids", "reports", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "pO", kwlist, &uses_ids, &reports)) {
        return -1;
    }
    PyObject *fast = PySequence_Fast(reports, "reports must be a sequence");
    if (fast == NULL) {
        return -1;
    }
    plan_free_reports(self);
    self->uses_ids = uses_ids;
    for (int i = 0; i < 256; i++) {
        self->by_id[i] = -1;
    }
    Py_ssize_t n = PySequence_Fast_GET_SIZE(fast);
    if (n < 1 || n > 256 || (!uses_ids && n != 1)) {
        Py_DECREF(fast);
        PyErr_SetString(PyExc_ValueError, "1 report without IDs, 1..256 with");
        return -1;
    }
    self->reports = PyMem_Calloc(n, sizeof(Report));
    if (self->reports == NULL) {
        Py_DECREF(fast);
        PyErr_NoMemory();
        return -1;
    }
    self->n_reports = n;
    for (Py_ssize_t i = 0; i < n; i++) {
        Report *r = &self->reports[i];
        PyObject *fields, *buttons;
        unsigned long long keep;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(fast, i), "inKOO", &r->report_id,
                              &r->length, &keep, &fields, &buttons)
            || (r->fields = parse_all(fields, sizeof(Field), parse_field, &r->n_fields)) == NULL
            || (r->buttons = parse_all(buttons, sizeof(Button), parse_button, &r->n_buttons))
                   == NULL) {
            Py_DECREF(fast);
            return -1;
        }
        r->keep = (uint64_t)keep;
        if (uses_ids) {
            if (r->report_id < 0 || r->report_id > 255) {
                Py_DECREF(fast);
                PyErr_SetString(PyExc_ValueError, "a report ID is a byte");
                return -1;
            }
            self->by_id[r->report_id] = (int)i;
        }
    }
    Py_DECREF(fast);
    return 0;
}

static int
append_int(PyObject *list, uint64_t v)
{
    PyObject *item = PyLong_FromUnsignedLongLong(v);
    if (item == NULL) {
        return -1;
    }
    int rc = PyList_Append(list, item);
    Py_DECREF(item);
    return rc;
}

static PyObject *
plan_drain(PlanObject *self, PyObject *args)
{
    PyObject *batch, *values;
    unsigned long long mask_in;
    int edges;
    if (!PyArg_ParseTuple(args, "O!O!Kp", &PyList_Type, &batch, &PyList_Type, &values, &mask_in,
                          &edges)) {
        return NULL;
    }
    Py_ssize_t last_of[256]; /* per report of the plan: index in batch of its last valid one */
    for (Py_ssize_t i = 0; i < self->n_reports; i++) {
        last_of[i] = -1;
    }
    PyObject *changes = PyList_New(0);
    if (changes == NULL) {
        return NULL;
    }
    uint64_t mask = (uint64_t)mask_in;
    Py_ssize_t n = PyList_GET_SIZE(batch), refused = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PyList_GET_ITEM(batch, i);
        if (!PyBytes_Check(item)) {
            Py_DECREF(changes);
            PyErr_SetString(PyExc_TypeError, "reports must be bytes");
            return NULL;
        }
        const unsigned char *p = (const unsigned char *)PyBytes_AS_STRING(item);
        Py_ssize_t len = PyBytes_GET_SIZE(item);
        int which = 0;
        if (self->uses_ids) {
            which = len > 0 ? self->by_id[p[0]] : -1;
        }
        if (which < 0 || len < self->reports[which].length) {
            refused++;
            continue;
        }
        const Report *r = &self->reports[which];
        last_of[which] = i;
        uint64_t b = report_buttons(r, p, len) | (mask & r->keep);
        if (b != mask) {
            uint64_t report = edges ? b & ~mask : b;
            mask = b;
            if ((!edges || report) && append_int(changes, report) < 0) {
                Py_DECREF(changes);
                return NULL;
            }
        }
    }
    for (Py_ssize_t k = 0; k < self->n_reports; k++) {
        if (last_of[k] < 0) {
            continue;
        }
        PyObject *item = PyList_GET_ITEM(batch, last_of[k]);
        const unsigned char *p = (const unsigned char *)PyBytes_AS_STRING(item);
        if (decode_values(&self->reports[k], p, PyBytes_GET_SIZE(item), values) < 0) {
            Py_DECREF(changes);
            return NULL;
        }
    }
    return Py_BuildValue("nnKN", n - refused, refused, (unsigned long long)mask,
                         changes);
}

/* Each character's value as a hex digit, -1 for any other (filled at import). */
static signed char hex_values[256];

static void
fill_hex_values(void)
{
    memset(hex_values, -1, sizeof hex_values);
    for (int k = 0; k < 10; k++) {
        hex_values['0' + k] = (signed char)k;
    }
    for (int k = 0; k < 6; k++) {
        hex_values['a' + k] = hex_values['A' + k] = (signed char)(10 + k);
    }
}

static int
hex_digit(unsigned char c)
{
    return hex_values[c];
}

/* What str.rstrip() strips, of ASCII (str.isspace). */
static int
is_space(unsigned char c)
{
    return c == ' ' || (c >= '\t' && c <= '\r') || (c >= 0x1c && c <= 0x1f);
}

/* The value of `n` characters of digits with at most one '.' inside, as float() reads
 * them: N / 10**k (N the digits as an integer, k those after the point) is one correctly
 * rounded division when N < 2**53 and 10**k is exact (k <= 22), which is float()'s own
 * answer; any other stamp is read by PyOS_string_to_double (float()'s parser). -1 when it
 * cannot be read or is not finite. */
static double
stamp_seconds(const char *s, Py_ssize_t n)
{
    static const double exact[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                   1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                   1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
    uint64_t digits = 0;
    int count = 0, after = -1;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (s[i] == '.') {
            after = 0;
            continue;
        }
        if (count < 19) {
            digits = digits * 10 + (uint64_t)(s[i] - '0');
        }
        count++;
        after += after >= 0;
    }
    int k = after < 0 ? 0 : after;
    if (count <= 15 && k <= 22) { /* 10**15 < 2**53 */
        return (double)digits / exact[k];
    }
    char stamp[48];
    memcpy(stamp, s, (size_t)n);
    stamp[n] = '\0';
    double t = PyOS_string_to_double(stamp, NULL, NULL);
    if (t == -1.0 && PyErr_Occurred()) {
        PyErr_Clear();
        return -1;
    }
    return isfinite(t) && t >= 0 ? t : -1;
}

/* One line as written, up to its report's hex: 1 with its time, where the hex starts and
 * how many bytes it gives; 0 when the line is not as written (no exception). */
static int
event_head(const char *s, Py_ssize_t n, double *time_s, Py_ssize_t *hex, Py_ssize_t *length)
{
    if (n < 3 || memcmp(s, "E: ", 3) != 0) {
        return 0;
    }
    Py_ssize_t i = 3, start = 3;
    int dots = 0;
    while (i < n && (isdigit((unsigned char)s[i]) || s[i] == '.')) {
        dots += s[i] == '.';
        i++;
    }
    if (i == start || i >= n || s[i] != ' ' || dots > 1 || s[start] == '.' || s[i - 1] == '.'
        || i - start > 40) {
        return 0;
    }
    double t = stamp_seconds(s + start, i - start);
    if (t < 0) {
        return 0;
    }
    i++;
    start = i;
    Py_ssize_t count = 0;
    while (i < n && isdigit((unsigned char)s[i]) && i - start < 7) {
        count = count * 10 + (s[i] - '0');
        i++;
    }
    if (i == start || i >= n || s[i] != ' ' || count < 1) {
        return 0;
    }
    i++;
    if (n - i < 3 * count - 1) {
        return 0;
    }
    *time_s = t;
    *hex = i;
    *length = count;
    return 1;
}

/* The report's `length` bytes from the hex at `hex` into `out`: two digits a byte, one space
 * apart, then whitespace only to the line's end (rstrip); 0 when they are not so. */
static int
event_bytes(const char *s, Py_ssize_t n, Py_ssize_t hex, Py_ssize_t length, unsigned char *out)
{
    Py_ssize_t i = hex;
    for (Py_ssize_t k = 0; k < length; k++, i += 3) {
        int hi = hex_digit((unsigned char)s[i]), lo = hex_digit((unsigned char)s[i + 1]);
        if (hi < 0 || lo < 0 || (k + 1 < length && s[i + 2] != ' ')) {
            return 0;
        }
        out[k] = (unsigned char)(hi << 4 | lo);
    }
    for (i -= 1; i < n; i++) { /* after the last pair: whitespace only (rstrip) */
        if (!is_space((unsigned char)s[i])) {
            return 0;
        }
    }
    return 1;
}

/* One line as written: 1 and its time and report, 0 when it is not (no exception). */
static int
parse_event(const char *s, Py_ssize_t n, double *time_s, PyObject **report)
{
    Py_ssize_t hex, length;
    if (!event_head(s, n, time_s, &hex, &length)) {
        return 0;
    }
    PyObject *bytes = PyBytes_FromStringAndSize(NULL, length);
    if (bytes == NULL) {
        PyErr_Clear();
        return 0;
    }
    if (!event_bytes(s, n, hex, length, (unsigned char *)PyBytes_AS_STRING(bytes))) {
        Py_DECREF(bytes);
        return 0;
    }
    *report = bytes;
    return 1;
}

static PyObject *
parse_events(PyObject *module, PyObject *lines)
{
    (void)module;
    PyObject *fast = PySequence_Fast(lines, "lines must be a sequence");
    if (fast == NULL) {
        return NULL;
    }
    Py_ssize_t n = PySequence_Fast_GET_SIZE(fast);
    PyObject *times = PyList_New(n), *reports = PyList_New(n), *result = NULL;
    if (times == NULL || reports == NULL || n == 0) {
        goto done; /* an empty batch is no batch: no verdict */
    }
    for (Py_ssize_t k = 0; k < n; k++) {
        PyObject *line = PySequence_Fast_GET_ITEM(fast, k);
        double t;
        PyObject *report = NULL, *stamp;
        Py_ssize_t size;
        const char *text = PyUnicode_Check(line) && PyUnicode_IS_ASCII(line)
                               ? PyUnicode_AsUTF8AndSize(line, &size)
                               : NULL;
        if (text == NULL || !parse_event(text, size, &t, &report)
            || (stamp = PyFloat_FromDouble(t)) == NULL) {
            Py_XDECREF(report);
            goto done;
        }
        PyList_SET_ITEM(times, k, stamp);
        PyList_SET_ITEM(reports, k, report);
    }
    result = Py_BuildValue("OO", times, reports);
done:
    Py_DECREF(fast);
    Py_XDECREF(times);
    Py_XDECREF(reports);
    if (result == NULL && !PyErr_Occurred()) {
        Py_RETURN_NONE; /* not every line as written: the Python parse decides */
    }
    return result;
}

/* Events: a block's events packed, played by the replay backend. */
typedef struct {
    PyObject_HEAD
    unsigned char *blob; /* the reports back to back */
    Py_ssize_t *starts;  /* report k is blob[starts[k]:starts[k + 1]] */
    double *times;       /* recorded, seconds */
    double *dues;        /* when each is due (schedule()); +inf before */
    Py_ssize_t n, next, blob_size;
} EventsObject;

static void
events_dealloc(EventsObject *self)
{
    PyMem_Free(self->blob);
    PyMem_Free(self->starts);
    PyMem_Free(self->times);
    PyMem_Free(self->dues);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int
events_grow(EventsObject *self, Py_ssize_t lines, Py_ssize_t bytes)
{
    unsigned char *blob = PyMem_Realloc(self->blob, (size_t)(bytes > 0 ? bytes : 1));
    if (blob == NULL) {
        return -1;
    }
    self->blob = blob;
    Py_ssize_t *starts = PyMem_Realloc(self->starts, sizeof(Py_ssize_t) * (size_t)(lines + 1));
    if (starts == NULL) {
        return -1;
    }
    self->starts = starts;
    double *times = PyMem_Realloc(self->times, sizeof(double) * (size_t)(lines > 0 ? lines : 1));
    if (times == NULL) {
        return -1;
    }
    self->times = times;
    return 0;
}

static PyTypeObject EventsType;

/* parse_packed(text): a block's complete lines, packed: (events, end, lines), or None. */
static PyObject *
parse_packed(PyObject *module, PyObject *text)
{
    (void)module;
    if (!PyUnicode_Check(text)) {
        PyErr_SetString(PyExc_TypeError, "text must be a str");
        return NULL;
    }
    if (!PyUnicode_IS_ASCII(text)) {
        Py_RETURN_NONE;
    }
    const char *s = (const char *)PyUnicode_DATA(text);
    Py_ssize_t n = PyUnicode_GET_LENGTH(text), start = 0;
    EventsObject *events = PyObject_New(EventsObject, &EventsType);
    if (events == NULL) {
        return NULL;
    }
    events->blob = NULL;
    events->starts = NULL;
    events->times = NULL;
    events->dues = NULL;
    events->n = events->next = 0;
    /* a line gives at most a third of its characters as bytes: one allocation each */
    Py_ssize_t lines_cap = 64, bytes_cap = n / 3 + 1;
    if (events_grow(events, lines_cap, bytes_cap) < 0) {
        Py_DECREF(events);
        return PyErr_NoMemory();
    }
    Py_ssize_t used = 0;
    events->starts[0] = 0;
    for (const char *newline; (newline = memchr(s + start, '\n', (size_t)(n - start)));) {
        Py_ssize_t i = newline - s;
        double t;
        Py_ssize_t hex, length;
        if (!event_head(s + start, i - start, &t, &hex, &length)) {
            Py_DECREF(events);
            Py_RETURN_NONE; /* not as written: no verdict */
        }
        if (events->n == lines_cap || used + length > bytes_cap) {
            lines_cap = events->n == lines_cap ? lines_cap * 2 : lines_cap;
            bytes_cap = used + length > bytes_cap ? 2 * (used + length) : bytes_cap;
            if (events_grow(events, lines_cap, bytes_cap) < 0) {
                Py_DECREF(events);
                return PyErr_NoMemory();
            }
        }
        if (!event_bytes(s + start, i - start, hex, length, events->blob + used)) {
            Py_DECREF(events);
            Py_RETURN_NONE;
        }
        events->times[events->n] = t;
        used += length;
        events->n++;
        events->starts[events->n] = used;
        start = i + 1;
    }
    if (events->n == 0) {
        Py_DECREF(events);
        Py_RETURN_NONE;
    }
    events->blob_size = used;
    events->dues = PyMem_Malloc(sizeof(double) * (size_t)events->n);
    if (events->dues == NULL) {
        Py_DECREF(events);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t k = 0; k < events->n; k++) {
        events->dues[k] = INFINITY;
    }
    return Py_BuildValue("Nnn", (PyObject *)events, start, events->n);
}

static PyObject *
events_schedule(EventsObject *self, PyObject *args)
{
    double start, speed, due;
    if (!PyArg_ParseTuple(args, "ddd", &start, &speed, &due)) {
        return NULL;
    }
    for (Py_ssize_t k = 0; k < self->n; k++) {
        double at = start + self->times[k] / speed;
        if (at > due) { /* max(due, at), as Python's max keeps the first of equals */
            due = at;
        }
        self->dues[k] = due;
    }
    return PyFloat_FromDouble(due);
}

static PyObject *
events_take(EventsObject *self, PyObject *args)
{
    double now;
    Py_ssize_t limit;
    if (!PyArg_ParseTuple(args, "dn", &now, &limit)) {
        return NULL;
    }
    Py_ssize_t first = self->next, end = first;
    while (end < self->n && end - first < limit && self->dues[end] <= now) {
        end++;
    }
    PyObject *taken = PyList_New(end - first);
    if (taken == NULL) {
        return NULL;
    }
    for (Py_ssize_t k = first; k < end; k++) {
        PyObject *report = PyBytes_FromStringAndSize(
            (const char *)self->blob + self->starts[k], self->starts[k + 1] - self->starts[k]);
        if (report == NULL) {
            Py_DECREF(taken);
            return NULL;
        }
        PyList_SET_ITEM(taken, k - first, report);
    }
    self->next = end;
    return taken;
}

static PyObject *
events_next_due(EventsObject *self, void *closure)
{
    (void)closure;
    return PyFloat_FromDouble(self->next < self->n ? self->dues[self->next] : INFINITY);
}

static PyObject *
events_last_time(EventsObject *self, void *closure)
{
    (void)closure;
    return PyFloat_FromDouble(self->times[self->n - 1]);
}

static PyObject *
events_left(EventsObject *self, void *closure)
{
    (void)closure;
    return PyLong_FromSsize_t(self->n - self->next);
}

static PyObject *
events_pairs(EventsObject *self, PyObject *unused)
{
    (void)unused;
    PyObject *times = PyList_New(self->n), *reports = PyList_New(self->n);
    if (times == NULL || reports == NULL) {
        Py_XDECREF(times);
        Py_XDECREF(reports);
        return NULL;
    }
    for (Py_ssize_t k = 0; k < self->n; k++) {
        PyObject *t = PyFloat_FromDouble(self->times[k]);
        PyObject *r = PyBytes_FromStringAndSize((const char *)self->blob + self->starts[k],
                                                self->starts[k + 1] - self->starts[k]);
        if (t == NULL || r == NULL) {
            Py_XDECREF(t);
            Py_XDECREF(r);
            Py_DECREF(times);
            Py_DECREF(reports);
            return NULL;
        }
        PyList_SET_ITEM(times, k, t);
        PyList_SET_ITEM(reports, k, r);
    }
    return Py_BuildValue("NN", times, reports);
}

static Py_ssize_t
events_len(EventsObject *self)
{
    return self->n;
}

static PySequenceMethods events_as_sequence = {
    .sq_length = (lenfunc)events_len,
};

static PyMethodDef events_methods[] = {
    {"schedule", (PyCFunction)events_schedule, METH_VARARGS,
     "schedule(start, speed, floor) -> the last due: each due start + t / speed, a running "
     "maximum from floor"},
    {"take", (PyCFunction)events_take, METH_VARARGS,
     "take(now, limit) -> the reports due at now, at most limit, from the first not taken"},
    {"pairs", (PyCFunction)events_pairs, METH_NOARGS,
     "pairs() -> (times, reports): every event, as lists"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef events_getset[] = {
    {"next_due", (getter)events_next_due, NULL, "when the first not taken is due (inf: none)",
     NULL},
    {"last_time", (getter)events_last_time, NULL, "the last event's recorded time", NULL},
    {"left", (getter)events_left, NULL, "how many are not taken yet", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject EventsType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "usb2rc.hid._speedups.Events",
    .tp_basicsize = sizeof(EventsObject),
    .tp_dealloc = (destructor)events_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "A block's events, packed (parse_packed), played in order.",
    .tp_methods = events_methods,
    .tp_getset = events_getset,
    .tp_as_sequence = &events_as_sequence,
};

/* pull(reader, device, now, limit, kept, bad_limit): a pulled reader's pull of a replay
 * device in one call, the compiled form of `reader.DeviceReader.pull` over
 * `replay.ReplayDevice.read_due`. It takes the reports due at `now` (at most `limit`) from
 * the batches in play (packed batches in place; a batch the Python parse made, and the next
 * block read from the file, through the replay's own methods), decodes each report ID's
 * last one into the decoder's values, notes every press (the press log keeps `kept`),
 * counts refused reports (`bad_limit` in a row: in error) and publishes the reader's
 * record, telling `on_bad_reports` of an edge: the Python pull's steps, on the reader's,
 * the decoder's and the device's own fields (it keeps no state of its own).
 * True: pulled (or nothing due, or the reader closed). False: declined before anything was
 * written: the device lock is taken (a close in progress), or the replay owes a read error
 * (a fault due, the file gone, the device closed); the Python pull then runs and raises it.
 * None: never (the decoder has no C plan, or the reader no button decoder). */

static PyObject *str_device_lock, *str_acquire, *str_release, *str_closed, *str_pull_error,
    *str_press_decoder, *str_refused_in_a_row, *str_last_report, *str_repeats, *str_reports,
    *str_bad_reports, *str_record, *str_presses, *str_press_serial, *str_bad_spells,
    *str_c_plan, *str_values, *str_buttons, *str_state, *str_dec_reports, *str_dec_bad_reports,
    *str_quiet_until, *str_set, *str_batch, *str_busy_s, *str_fault_due,
    *str_gone, *str_refill, *str_left, *str_on_bad_reports,
    *str_field_values, *str_field_buttons, *str_next_gone_check, *str_stat_path, *str_stat_id,
    *str_gone_check_s, *str_read_fd, *str_pending, *str_failed_read, *str_drained_full, *str_drained;

static int
intern_pull_names(void)
{
    struct {
        PyObject **slot;
        const char *text;
    } names[] = {
        {&str_device_lock, "_device_lock"}, {&str_acquire, "acquire"},
        {&str_release, "release"}, {&str_closed, "_closed"},
        {&str_pull_error, "_pull_error"}, {&str_press_decoder, "_press_decoder"},
        {&str_refused_in_a_row, "_refused_in_a_row"}, {&str_last_report, "_last_report"},
        {&str_repeats, "_repeats"}, {&str_reports, "_reports"},
        {&str_bad_reports, "_bad_reports"}, {&str_record, "record"},
        {&str_presses, "_presses"}, {&str_press_serial, "_press_serial"},
        {&str_bad_spells, "_bad_spells"}, {&str_c_plan, "_c_plan"},
        {&str_values, "_values"}, {&str_buttons, "_buttons"}, {&str_state, "_state"},
        {&str_dec_reports, "reports"}, {&str_dec_bad_reports, "bad_reports"},
        {&str_quiet_until, "_quiet_until"}, {&str_set, "_set"}, {&str_batch, "_batch"},
        {&str_busy_s, "busy_s"},
        {&str_fault_due, "_fault_due"}, {&str_gone, "_gone"},
        {&str_refill, "_refill"}, {&str_left, "left"},
        {&str_on_bad_reports, "on_bad_reports"},
        {&str_field_values, "values"}, {&str_field_buttons, "buttons"},
        {&str_next_gone_check, "_next_gone_check"}, {&str_stat_path, "_stat_path"},
        {&str_stat_id, "_stat_id"}, {&str_gone_check_s, "_gone_check_s"},
        {&str_read_fd, "read_fd"}, {&str_pending, "_pending"},
        {&str_failed_read, "failed_read"}, {&str_drained_full, "drained_a_full_queue"},
        {&str_drained, "_drained"},
    };
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        if ((*names[i].slot = PyUnicode_InternFromString(names[i].text)) == NULL) {
            return -1;
        }
    }
    return 0;
}

/* obj.name as a double; -1 with an exception. */
static int
attr_double(PyObject *obj, PyObject *name, double *out)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    *out = PyFloat_AsDouble(v);
    Py_DECREF(v);
    return *out == -1.0 && PyErr_Occurred() ? -1 : 0;
}

/* obj.name as a Py_ssize_t; -1 with an exception. */
static int
attr_ssize(PyObject *obj, PyObject *name, Py_ssize_t *out)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    *out = PyLong_AsSsize_t(v);
    Py_DECREF(v);
    return *out == -1 && PyErr_Occurred() ? -1 : 0;
}

/* obj.name = value (a new reference, taken); -1 with an exception. */
static int
attr_set_new(PyObject *obj, PyObject *name, PyObject *value)
{
    if (value == NULL) {
        return -1;
    }
    int rc = PyObject_SetAttr(obj, name, value);
    Py_DECREF(value);
    return rc;
}

/* obj.name += add (an int); -1 with an exception. */
static int
attr_add(PyObject *obj, PyObject *name, Py_ssize_t add)
{
    Py_ssize_t v;
    if (add == 0) {
        return 0; /* `+= 0` leaves the same int: nothing to read or write */
    }
    if (attr_ssize(obj, name, &v) < 0) {
        return -1;
    }
    return attr_set_new(obj, name, PyLong_FromSsize_t(v + add));
}

/* obj.name += add (a float); -1 with an exception. */
static int
attr_add_double(PyObject *obj, PyObject *name, double add)
{
    double v;
    if (attr_double(obj, name, &v) < 0) {
        return -1;
    }
    return attr_set_new(obj, name, PyFloat_FromDouble(v + add));
}

/* obj.name is truthy: 1, 0, or -1 with an exception. */
static int
attr_true(PyObject *obj, PyObject *name)
{
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) {
        return -1;
    }
    int truth = PyObject_IsTrue(v);
    Py_DECREF(v);
    return truth;
}

static double
monotonic_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

#define MAX_TAKE 1024 /* reports a pull takes at most (the reader's MAX_BATCH is less) */

/* A pull in progress: what it took and what it made of it. */
typedef struct {
    PyObject *decoder, *plan, *values, *held; /* held: what keeps the taken reports alive */
    const unsigned char *report[MAX_TAKE];
    Py_ssize_t length[MAX_TAKE], n;
    uint64_t mask, pressed[MAX_TAKE];
    Py_ssize_t presses, refused, last_of[256];
    double taken_at; /* when the reports due were taken: the replay's own part ends */
} Pull;

static void
pull_clear(Pull *s)
{
    Py_CLEAR(s->decoder);
    Py_CLEAR(s->plan);
    Py_CLEAR(s->values);
    Py_CLEAR(s->held);
}

/* Whether the file at `path` (bytes) is the one of `id`, a stat id as `replay._id_of` makes
 * it (inode, mtime in ns, size): 1 yes, 0 no (or it cannot be stat'ed), -1 with an
 * exception. */
static int
same_file(PyObject *path, PyObject *id)
{
    if (!PyBytes_Check(path) || !PyTuple_Check(id) || PyTuple_GET_SIZE(id) != 3) {
        PyErr_SetString(PyExc_TypeError, "a replay's stat path is bytes, its stat id 3 ints");
        return -1;
    }
    unsigned long long inode = PyLong_AsUnsignedLongLong(PyTuple_GET_ITEM(id, 0));
    long long mtime_ns = PyLong_AsLongLong(PyTuple_GET_ITEM(id, 1));
    long long size = PyLong_AsLongLong(PyTuple_GET_ITEM(id, 2));
    if (PyErr_Occurred()) {
        return -1;
    }
    struct stat st;
    if (stat(PyBytes_AS_STRING(path), &st) != 0) {
        return 0; /* gone (or unreadable): the Python check says which */
    }
    long long st_mtime_ns = (long long)st.st_mtim.tv_sec * 1000000000LL + st.st_mtim.tv_nsec;
    return (unsigned long long)st.st_ino == inode && st_mtime_ns == mtime_ns
           && (long long)st.st_size == size;
}

/* `ReplayDevice._check_gone(now)` while its file is there, without a Python call: nothing
 * before the next check is due; then a stat, and the next check `_gone_check_s` later. 1:
 * done; 0: the file is not the one plugged (the Python check then says so, and raises); -1
 * with an exception. */
static int
gone_check(PyObject *device, double now, double fault_due)
{
    double next_check, every;
    if (attr_double(device, str_next_gone_check, &next_check) < 0) {
        return -1;
    }
    if (now < next_check) {
        return 1;
    }
    PyObject *path = PyObject_GetAttr(device, str_stat_path);
    PyObject *id = path == NULL ? NULL : PyObject_GetAttr(device, str_stat_id);
    int same = id == NULL ? -1 : same_file(path, id);
    Py_XDECREF(path);
    Py_XDECREF(id);
    if (same <= 0) {
        return same;
    }
    if (attr_double(device, str_gone_check_s, &every) < 0) {
        return -1;
    }
    next_check = now + every;
    if (attr_set_new(device, str_next_gone_check, PyFloat_FromDouble(next_check)) < 0) {
        return -1;
    }
    return attr_set_new(device, str_quiet_until,
                        PyFloat_FromDouble(fault_due < next_check ? fault_due : next_check));
}

/* The replay's gone check when it is due, as `ReplayDevice.read_due` makes it (a stat at
 * most every GONE_CHECK_S, made here while the file is there; DeviceGone raised by the
 * Python check once it is not); then whether the
 * replay may hand reports over now: 1 yes, 0 no (its read raises: a fault due, the file
 * gone, the device closed), -1 with an exception. */
static int
replay_ready(PyObject *device, double now)
{
    double quiet_until, fault_due;
    if (attr_double(device, str_quiet_until, &quiet_until) < 0) {
        return -1;
    }
    if (!(now < quiet_until)) {
        PyObject *gone = PyObject_GetAttr(device, str_gone);
        if (gone == NULL || attr_double(device, str_fault_due, &fault_due) < 0) {
            Py_XDECREF(gone);
            return -1;
        }
        int known_gone = gone != Py_None;
        Py_DECREF(gone);
        if (quiet_until <= now && now < fault_due && !known_gone) {
            int there = gone_check(device, now, fault_due);
            if (there < 0) {
                return -1;
            }
            if (!there) { /* the Python check says how it is gone, and raises */
                PyObject *done = PyObject_CallMethod(device, "_check_gone", "d", now);
                if (done == NULL) {
                    return -1;
                }
                Py_DECREF(done);
            }
        }
        if (attr_double(device, str_quiet_until, &quiet_until) < 0) {
            return -1;
        }
        if (!(now < quiet_until)) {
            return 0;
        }
    }
    PyObject *flag = PyObject_GetAttr(device, str_closed);
    if (flag == NULL) {
        return -1;
    }
    int closed = attr_true(flag, str_set);
    Py_DECREF(flag);
    return closed < 0 ? -1 : !closed;
}

/* A report taken: kept for the decode (its owner is in s->held). */
static void
took(Pull *s, const unsigned char *p, Py_ssize_t len)
{
    s->report[s->n] = p;
    s->length[s->n] = len;
    s->n++;
}

/* One batch's reports due, at most `room`: a packed batch's in place, another's through its
 * `take`; 1 when the batch holds more (the next is not due, or the room is used up), 0
 * when it is spent, -1 with an exception. */
static int
take_from(Pull *s, PyObject *batch, double now, Py_ssize_t room)
{
    if (PyList_Append(s->held, batch) < 0) {
        return -1;
    }
    if (PyObject_TypeCheck(batch, &EventsType)) {
        EventsObject *events = (EventsObject *)batch;
        Py_ssize_t k = events->next;
        for (; k < events->n && k - events->next < room && events->dues[k] <= now; k++) {
            took(s, events->blob + events->starts[k], events->starts[k + 1] - events->starts[k]);
        }
        events->next = k;
        return k < events->n;
    }
    PyObject *taken = PyObject_CallMethod(batch, "take", "dn", now, room);
    if (taken == NULL || PyList_Append(s->held, taken) < 0) {
        Py_XDECREF(taken);
        return -1;
    }
    Py_ssize_t count = PyList_Check(taken) ? PyList_GET_SIZE(taken) : -1;
    for (Py_ssize_t i = 0; i < count && i < room; i++) {
        PyObject *report = PyList_GET_ITEM(taken, i);
        if (!PyBytes_Check(report)) {
            count = -1;
            break;
        }
        took(s, (const unsigned char *)PyBytes_AS_STRING(report), PyBytes_GET_SIZE(report));
    }
    Py_DECREF(taken);
    if (count < 0 || count > room) {
        PyErr_SetString(PyExc_TypeError, "a batch's take gives at most room reports, as bytes");
        return -1;
    }
    Py_ssize_t left;
    return attr_ssize(batch, str_left, &left) < 0 ? -1 : left > 0;
}

/* The reports due, as `ReplayDevice.read_due(limit)` takes them: from the batch in play, the
 * next block read when it is spent (`_refill`), until one is not due or `limit` are taken.
 * 0, or -1 with an exception. */
static int
take_due(PyObject *device, double now, Py_ssize_t limit, Pull *s)
{
    while (s->n < limit) {
        PyObject *batch = PyObject_GetAttr(device, str_batch);
        if (batch == NULL) {
            return -1;
        }
        Py_ssize_t left = 0;
        int more = 0;
        if (PyObject_TypeCheck(batch, &EventsType)) {
            left = ((EventsObject *)batch)->n - ((EventsObject *)batch)->next;
        } else if (attr_ssize(batch, str_left, &left) < 0) {
            Py_DECREF(batch);
            return -1;
        }
        if (left > 0) {
            more = take_from(s, batch, now, limit - s->n);
            Py_DECREF(batch);
            if (more != 0) {
                return more < 0 ? -1 : 0; /* the next one is not due yet (or the limit) */
            }
            continue;
        }
        Py_DECREF(batch);
        PyObject *refilled = PyObject_CallMethodNoArgs(device, str_refill);
        int next = refilled == NULL ? -1 : PyObject_IsTrue(refilled);
        Py_XDECREF(refilled);
        if (next <= 0) {
            return next; /* no batch left (or its block is bad: the next read says so) */
        }
    }
    return 0;
}

/* The reports taken, scanned as `plan.drain(..., edges=True)` takes them: the refused ones
 * counted, each report ID's last accepted one found, the mask after them, and the buttons
 * each accepted report pressed, for each that pressed one. */
static void
scan(Pull *s)
{
    const PlanObject *plan = (const PlanObject *)s->plan;
    for (Py_ssize_t i = 0; i < plan->n_reports; i++) {
        s->last_of[i] = -1;
    }
    s->presses = s->refused = 0;
    for (Py_ssize_t k = 0; k < s->n; k++) {
        const unsigned char *p = s->report[k];
        Py_ssize_t len = s->length[k];
        int which = plan->uses_ids ? (len > 0 ? plan->by_id[p[0]] : -1) : 0;
        if (which < 0 || len < plan->reports[which].length) {
            s->refused++;
            continue;
        }
        const Report *r = &plan->reports[which];
        uint64_t b = report_buttons(r, p, len) | (s->mask & r->keep);
        if (b & ~s->mask) {
            s->pressed[s->presses++] = b & ~s->mask;
        }
        s->mask = b;
        s->last_of[which] = k;
    }
}

/* Reports taken byte for byte the same as the one before (the first against `before`), as
 * the reader counts `repeats`. */
static Py_ssize_t
count_repeats(const Pull *s, PyObject *before)
{
    const unsigned char *prev = (const unsigned char *)PyBytes_AS_STRING(before);
    Py_ssize_t prev_len = PyBytes_GET_SIZE(before), repeats = 0;
    for (Py_ssize_t k = 0; k < s->n; k++) {
        repeats += s->length[k] == prev_len && memcmp(s->report[k], prev, (size_t)prev_len) == 0;
        prev = s->report[k];
        prev_len = s->length[k];
    }
    return repeats;
}

/* Every press noted, as `DeviceReader._note_presses`: the press log the last `kept` of the
 * old one and these, the serial on by their count. */
static int
note_presses(PyObject *reader, const Pull *s, Py_ssize_t kept)
{
    PyObject *old = PyObject_GetAttr(reader, str_presses);
    if (old == NULL) {
        return -1;
    }
    if (!PyTuple_Check(old)) {
        Py_DECREF(old);
        PyErr_SetString(PyExc_TypeError, "a reader's presses are a tuple");
        return -1;
    }
    Py_ssize_t n_old = PyTuple_GET_SIZE(old), total = n_old + s->presses;
    Py_ssize_t skip = total > kept ? total - kept : 0, size = total - skip;
    PyObject *log = PyTuple_New(size);
    for (Py_ssize_t i = 0; log != NULL && i < size; i++) {
        Py_ssize_t at = skip + i;
        PyObject *item = at < n_old ? Py_NewRef(PyTuple_GET_ITEM(old, at))
                                    : PyLong_FromUnsignedLongLong(s->pressed[at - n_old]);
        if (item == NULL) {
            Py_CLEAR(log);
            break;
        }
        PyTuple_SET_ITEM(log, i, item);
    }
    Py_DECREF(old);
    if (log == NULL) {
        return -1;
    }
    if (attr_add(reader, str_press_serial, s->presses) < 0) {
        Py_DECREF(log);
        return -1;
    }
    return attr_set_new(reader, str_presses, log);
}

/* What the decoder takes from the batch, as `ReportDecoder.feed_presses` with the C drain:
 * each report ID's last accepted report decoded into its values, its mask and counts. */
static int
decode(Pull *s)
{
    const PlanObject *plan = (const PlanObject *)s->plan;
    for (Py_ssize_t k = 0; k < plan->n_reports; k++) {
        Py_ssize_t at = s->last_of[k];
        if (at >= 0 && decode_values(&plan->reports[k], s->report[at], s->length[at], s->values) < 0) {
            return -1;
        }
    }
    Py_ssize_t accepted = s->n - s->refused;
    if (accepted
        && (attr_set_new(s->decoder, str_buttons, PyLong_FromUnsignedLongLong(s->mask)) < 0
            || PyObject_SetAttr(s->decoder, str_state, Py_None) < 0)) {
        return -1;
    }
    return attr_add(s->decoder, str_dec_reports, accepted) < 0
                   || attr_add(s->decoder, str_dec_bad_reports, s->refused) < 0
               ? -1
               : 0;
}

/* The reader's counts after the batch, as `DeviceReader._drain` and `_count_refused`. */
static int
count(PyObject *reader, const Pull *s, Py_ssize_t kept, Py_ssize_t bad_limit)
{
    Py_ssize_t accepted = s->n - s->refused, in_a_row;
    if (s->presses && note_presses(reader, s, kept) < 0) {
        return -1;
    }
    if (!s->refused) { /* a run of the same refused report is no sign of streaming */
        PyObject *before = PyObject_GetAttr(reader, str_last_report);
        if (before == NULL) {
            return -1;
        }
        Py_ssize_t repeats = PyBytes_Check(before) ? count_repeats(s, before) : -1;
        Py_DECREF(before);
        if (repeats < 0) {
            PyErr_SetString(PyExc_TypeError, "a reader's last report is bytes");
            return -1;
        }
        if (attr_add(reader, str_repeats, repeats) < 0) {
            return -1;
        }
    }
    PyObject *last = PyBytes_FromStringAndSize((const char *)s->report[s->n - 1],
                                               s->length[s->n - 1]);
    if (attr_set_new(reader, str_last_report, last) < 0 || attr_add(reader, str_reports, accepted) < 0
        || attr_add(reader, str_bad_reports, s->refused) < 0) {
        return -1;
    }
    if (accepted) {
        return attr_set_new(reader, str_refused_in_a_row, PyLong_FromLong(0));
    }
    if (attr_ssize(reader, str_refused_in_a_row, &in_a_row) < 0
        || attr_set_new(reader, str_refused_in_a_row, PyLong_FromSsize_t(in_a_row + s->refused))
               < 0) {
        return -1;
    }
    if (in_a_row < bad_limit && bad_limit <= in_a_row + s->refused) {
        return attr_add(reader, str_bad_spells, 1);
    }
    return 0;
}

/* A record's field `i` as a Py_ssize_t; -1 with an exception. */
static int
field_ssize(PyObject *record, Py_ssize_t i, Py_ssize_t *out)
{
    *out = PyLong_AsSsize_t(PyTuple_GET_ITEM(record, i));
    return *out == -1 && PyErr_Occurred() ? -1 : 0;
}

enum { R_REPORTS = 1, R_BAD = 2, R_AT = 3, R_IN_A_ROW = 6, R_SPELLS = 7, R_FIELDS = 9 };

/* The decoder's state, as `ReportDecoder.state()`: its last one while its values did not
 * change, else a new InputState (of the class of `like`, the last record's) of its values
 * and mask, kept as its last. Made as the frozen dataclass's __init__ makes it (its two
 * fields set through object.__setattr__), without running Python code. */
static PyObject *
decoder_state(PyObject *decoder, PyObject *like)
{
    PyObject *state = PyObject_GetAttr(decoder, str_state);
    if (state == NULL || state != Py_None) {
        return state;
    }
    Py_DECREF(state);
    PyObject *values = PyObject_GetAttr(decoder, str_values);
    PyObject *buttons = PyObject_GetAttr(decoder, str_buttons);
    PyObject *frozen = values == NULL ? NULL : PySequence_Tuple(values);
    PyObject *none = PyTuple_New(0);
    state = frozen == NULL || buttons == NULL || none == NULL
                ? NULL
                : PyBaseObject_Type.tp_new(Py_TYPE(like), none, NULL);
    if (state != NULL
        && (PyObject_GenericSetAttr(state, str_field_values, frozen) < 0
            || PyObject_GenericSetAttr(state, str_field_buttons, buttons) < 0
            || PyObject_SetAttr(decoder, str_state, state) < 0)) {
        Py_CLEAR(state);
    }
    Py_XDECREF(values);
    Py_XDECREF(buttons);
    Py_XDECREF(frozen);
    Py_XDECREF(none);
    return state;
}

/* A ReaderRecord (`cls`, a NamedTuple: a tuple subclass without a dict) of `fields`, as
 * tuple.__new__(cls, fields) makes it, without running Python code (as _steady.c's make). */
static PyObject *
new_record(PyTypeObject *cls, PyObject *const *fields)
{
    PyObject *record = cls->tp_alloc(cls, R_FIELDS);
    if (record == NULL) {
        return NULL;
    }
    for (int i = 0; i < R_FIELDS; i++) {
        PyTuple_SET_ITEM(record, i, Py_NewRef(fields[i]));
    }
    return record;
}

/* The reader's record published anew when its counts changed, as `DeviceReader._publish`;
 * `on_bad_reports` told of an edge. */
static int
publish(PyObject *reader, PyObject *decoder, double now, Py_ssize_t bad_limit)
{
    /* the record's fields after its time, in order, by the reader's attribute */
    static PyObject *const *after_at[R_FIELDS - R_AT - 1] = {
        &str_presses, &str_press_serial, &str_refused_in_a_row, &str_bad_spells, &str_repeats};
    PyObject *last = PyObject_GetAttr(reader, str_record), *record = NULL;
    PyObject *args[R_FIELDS] = {NULL};
    Py_ssize_t reports, bad, last_reports, last_bad, v[4];
    int rc = -1;
    /* the counts read once: compared here, published as they are */
    args[1] = PyObject_GetAttr(reader, str_reports);
    args[2] = PyObject_GetAttr(reader, str_bad_reports);
    if (last == NULL || args[1] == NULL || args[2] == NULL
        || ((reports = PyLong_AsSsize_t(args[1])) == -1 && PyErr_Occurred())
        || ((bad = PyLong_AsSsize_t(args[2])) == -1 && PyErr_Occurred())) {
        goto done;
    }
    if (!PyTuple_Check(last) || PyTuple_GET_SIZE(last) != R_FIELDS) {
        PyErr_SetString(PyExc_TypeError, "a reader's record is a ReaderRecord");
        goto done;
    }
    if (field_ssize(last, R_REPORTS, &last_reports) < 0 || field_ssize(last, R_BAD, &last_bad) < 0) {
        goto done;
    }
    if (last_reports == reports && last_bad == bad) {
        rc = 0;
        goto done;
    }
    if ((args[0] = decoder_state(decoder, PyTuple_GET_ITEM(last, 0))) == NULL) {
        goto done;
    }
    args[R_AT] = reports != last_reports ? PyFloat_FromDouble(now)
                                         : Py_NewRef(PyTuple_GET_ITEM(last, R_AT));
    for (int i = R_AT; args[i] != NULL && i < R_FIELDS - 1; i++) {
        args[i + 1] = PyObject_GetAttr(reader, *after_at[i - R_AT]);
    }
    if (args[R_FIELDS - 1] == NULL || (record = new_record(Py_TYPE(last), args)) == NULL
        || PyObject_SetAttr(reader, str_record, record) < 0) {
        goto done;
    }
    if (field_ssize(record, R_IN_A_ROW, &v[0]) < 0 || field_ssize(last, R_IN_A_ROW, &v[1]) < 0
        || field_ssize(record, R_SPELLS, &v[2]) < 0 || field_ssize(last, R_SPELLS, &v[3]) < 0) {
        goto done;
    }
    int edge = v[2] != v[3] || (v[0] != v[1] && (v[0] >= bad_limit) != (v[1] >= bad_limit));
    rc = 0;
    if (edge) {
        PyObject *tell = PyObject_GetAttr(reader, str_on_bad_reports);
        if (tell == NULL) {
            rc = -1;
        } else if (tell != Py_None) {
            PyObject *told = PyObject_CallFunctionObjArgs(tell, reader, record, NULL);
            rc = told == NULL ? -1 : 0;
            Py_XDECREF(told);
        }
        Py_XDECREF(tell);
    }
done:
    for (int i = 0; i < R_FIELDS; i++) {
        Py_XDECREF(args[i]);
    }
    Py_XDECREF(record);
    Py_XDECREF(last);
    return rc;
}

/* The decoder the pull feeds, its C plan, its values and mask: 1, 0 (never: no button
 * decoder, or no C plan), -1 with an exception. */
static int
pull_decoder(PyObject *reader, Pull *s)
{
    if ((s->decoder = PyObject_GetAttr(reader, str_press_decoder)) == NULL) {
        return -1;
    }
    if (s->decoder == Py_None) {
        return 0;
    }
    if ((s->plan = PyObject_GetAttr(s->decoder, str_c_plan)) == NULL) {
        return -1;
    }
    if (!PyObject_TypeCheck(s->plan, &PlanType)) {
        return 0;
    }
    PyObject *buttons = PyObject_GetAttr(s->decoder, str_buttons);
    if (buttons == NULL) {
        return -1;
    }
    s->mask = PyLong_AsUnsignedLongLong(buttons);
    Py_DECREF(buttons);
    if (s->mask == (uint64_t)-1 && PyErr_Occurred()) {
        return -1;
    }
    if ((s->values = PyObject_GetAttr(s->decoder, str_values)) == NULL) {
        return -1;
    }
    return PyList_Check(s->values) ? 1 : 0;
}

/* What every pull checks first, under the lock: 1 it goes on (the decoder and its C plan in
 * `s`), 0 it does nothing more (the reader closed, or a pull failed: as in Python), -2 never
 * (no button decoder, or no C plan), -1 with an exception. */
static int
pull_begins(PyObject *reader, Pull *s)
{
    int gone = attr_true(reader, str_closed);
    if (gone == 0) {
        PyObject *error = PyObject_GetAttr(reader, str_pull_error);
        gone = error == NULL ? -1 : error != Py_None;
        Py_XDECREF(error);
    }
    if (gone != 0) {
        return gone < 0 ? -1 : 0;
    }
    int ready = pull_decoder(reader, s);
    return ready < 0 ? -1 : ready == 0 ? -2 : 1;
}

/* The reports taken, decoded, counted and published: 1, or -1 with an exception. */
static int
pull_taken(PyObject *reader, double now, const Py_ssize_t *limits, Pull *s)
{
    if (s->n == 0) {
        return 1;
    }
    scan(s);
    if (decode(s) < 0 || count(reader, s, limits[1], limits[2]) < 0
        || publish(reader, s->decoder, now, limits[2]) < 0) {
        return -1;
    }
    return 1;
}

/* The replay's pull under the device lock: 1 pulled, 0 declined, -2 never, -1 with an
 * exception. */
static int
pull_locked(PyObject *reader, PyObject *device, double now, const Py_ssize_t *limits,
            Pull *s)
{
    int ready = pull_begins(reader, s);
    if (ready != 1) {
        return ready == 0 ? 1 : ready; /* closed, or a pull failed: pulled (nothing more) */
    }
    double started = monotonic_now();
    if ((ready = replay_ready(device, now)) <= 0) {
        return ready;
    }
    if ((s->held = PyList_New(0)) == NULL || take_due(device, now, limits[0], s) < 0) {
        return -1;
    }
    s->taken_at = monotonic_now();
    if (attr_add_double(device, str_busy_s, s->taken_at - started) < 0) {
        return -1;
    }
    return pull_taken(reader, now, limits, s);
}

#define FD_READ_SIZE 1024 /* hidapi_backend.READ_SIZE: more than any input report */
#define KERNEL_QUEUE_REPORTS 63 /* hidapi_backend.KERNEL_QUEUE_REPORTS: a hidraw fd's queue */

/* The reports a hidraw node has queued, as `HidapiDevice.read(0.0)` reads them on its own
 * non-blocking fd: one report a read(), until none is left (EAGAIN) or `limit` are taken,
 * kept in one bytearray (s->held). 0; 1: a read failed, its errno in *failed (ENODEV: it
 * read nothing, the node hung up; the reports read before it are dropped, as the Python
 * pull drops the batch its read raised in); -1 with an exception. */
static int
take_fd(int fd, Py_ssize_t limit, Pull *s, int *failed)
{
    Py_ssize_t size = 0, capacity = 16 * FD_READ_SIZE, at[MAX_TAKE];
    if ((s->held = PyByteArray_FromStringAndSize(NULL, capacity)) == NULL) {
        return -1;
    }
    while (s->n < limit) {
        if (capacity - size < FD_READ_SIZE) {
            capacity *= 2;
            if (PyByteArray_Resize(s->held, capacity) < 0) {
                return -1;
            }
        }
        ssize_t got = read(fd, PyByteArray_AS_STRING(s->held) + size, FD_READ_SIZE);
        if (got < 0 && errno == EINTR) {
            continue;
        }
        if (got < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            break;
        }
        if (got <= 0) { /* 0: the node hung up (a report is never empty) */
            *failed = got < 0 ? errno : ENODEV;
            s->n = 0;
            return 1;
        }
        at[s->n] = size;
        s->length[s->n++] = got;
        size += got;
    }
    const unsigned char *base = (const unsigned char *)PyByteArray_AS_STRING(s->held);
    for (Py_ssize_t i = 0; i < s->n; i++) {
        s->report[i] = base + at[i];
    }
    return 0;
}

/* The drain's count, as `HidapiDevice._read_fd` keeps it: `n` more reports read from the fd
 * (`_drained`, the drain's so far: a pull that stopped at its limit goes on with the next);
 * at its end (`dry`: a read found none), a drain that read as many as the kernel queues
 * tells the device (`drained_a_full_queue`). 0, or -1 with an exception. */
static int
drain_counted(PyObject *device, Py_ssize_t n, int dry)
{
    Py_ssize_t drained;
    if (attr_ssize(device, str_drained, &drained) < 0) {
        return -1;
    }
    Py_ssize_t before = drained;
    drained += n;
    if (!dry || before != 0) {
        if (attr_set_new(device, str_drained, PyLong_FromSsize_t(dry ? 0 : drained)) < 0) {
            return -1;
        }
    }
    if (!dry || drained < KERNEL_QUEUE_REPORTS) {
        return 0;
    }
    PyObject *count = PyLong_FromSsize_t(drained);
    PyObject *told = count == NULL ? NULL
                                   : PyObject_CallMethodOneArg(device, str_drained_full, count);
    Py_XDECREF(count);
    Py_XDECREF(told);
    return told == NULL ? -1 : 0;
}

/* A hidraw device's pull under the device lock: 1 pulled, 0 declined (reports from the open
 * still pending, or a read failed: the Python pull hands the first over and raises the
 * second), -2 never (no fd of its own, no C plan), -1 with an exception. */
static int
pull_fd_locked(PyObject *reader, PyObject *device, double now, const Py_ssize_t *limits,
               Pull *s)
{
    int ready = pull_begins(reader, s);
    if (ready != 1) {
        return ready == 0 ? 1 : ready;
    }
    PyObject *fd_obj = PyObject_GetAttr(device, str_read_fd);
    if (fd_obj == NULL) {
        return -1;
    }
    long fd = fd_obj == Py_None ? -1 : PyLong_AsLong(fd_obj);
    Py_DECREF(fd_obj);
    if (fd < 0 || fd > INT_MAX) {
        return PyErr_Occurred() ? -1 : -2;
    }
    PyObject *pending = PyObject_GetAttr(device, str_pending);
    int waiting = pending == NULL ? -1 : PyObject_IsTrue(pending);
    Py_XDECREF(pending);
    PyObject *failed_read = waiting != 0 ? NULL : PyObject_GetAttr(device, str_failed_read);
    if (waiting < 0 || (waiting == 0 && failed_read == NULL)) {
        return -1;
    }
    int failed = failed_read != NULL && failed_read != Py_None;
    Py_XDECREF(failed_read);
    if (waiting || failed) {
        return 0;
    }
    if (take_fd((int)fd, limits[0], s, &failed) < 0) {
        return -1;
    }
    if (failed) {
        return attr_set_new(device, str_failed_read, PyLong_FromLong(failed)) < 0 ? -1 : 0;
    }
    if (drain_counted(device, s->n, s->n < limits[0]) < 0) {
        return -1;
    }
    return pull_taken(reader, now, limits, s);
}

typedef int (*PullLocked)(PyObject *, PyObject *, double, const Py_ssize_t *, Pull *);

/* The pull's arguments read, the device lock taken without waiting, `under_lock` run under it;
 * `name`: the function called, for its errors. */
static PyObject *
pull_with(const char *name, PullLocked under_lock, PyObject *const *args, Py_ssize_t nargs)
{
    double now;
    Py_ssize_t limits[3]; /* limit, kept, bad_limit */
    if (nargs != 6) {
        PyErr_Format(PyExc_TypeError, "%s(reader, device, now, limit, kept, bad_limit)", name);
        return NULL;
    }
    if ((now = PyFloat_AsDouble(args[2])) == -1.0 && PyErr_Occurred()) {
        return NULL;
    }
    for (int i = 0; i < 3; i++) {
        if ((limits[i] = PyLong_AsSsize_t(args[3 + i])) == -1 && PyErr_Occurred()) {
            return NULL;
        }
    }
    if (limits[0] < 1 || limits[0] > MAX_TAKE || limits[1] < 1 || limits[2] < 1) {
        PyErr_Format(PyExc_ValueError, "%s: limit 1..%d, kept and bad_limit 1 or more", name,
                     (int)MAX_TAKE);
        return NULL;
    }
    PyObject *reader = args[0], *device = args[1];
    PyObject *lock = PyObject_GetAttr(reader, str_device_lock);
    if (lock == NULL) {
        return NULL;
    }
    PyObject *got = PyObject_CallMethodOneArg(lock, str_acquire, Py_False);
    int locked = got == NULL ? -1 : PyObject_IsTrue(got);
    Py_XDECREF(got);
    if (locked <= 0) {
        Py_DECREF(lock);
        if (locked < 0) {
            return NULL;
        }
        Py_RETURN_FALSE; /* a close in progress: the Python pull waits for it */
    }
    Pull s; /* not zeroed whole: its arrays are written before they are read */
    s.decoder = s.plan = s.values = s.held = NULL;
    s.n = 0;
    int rc = under_lock(reader, device, now, limits, &s);
    pull_clear(&s);
    PyObject *type, *value, *traceback;
    PyErr_Fetch(&type, &value, &traceback);
    PyObject *released = PyObject_CallMethodNoArgs(lock, str_release);
    Py_DECREF(lock);
    if (released == NULL) {
        Py_XDECREF(type);
        Py_XDECREF(value);
        Py_XDECREF(traceback);
        return NULL;
    }
    Py_DECREF(released);
    if (rc == -1) {
        PyErr_Restore(type, value, traceback);
        return NULL;
    }
    if (rc == -2) {
        Py_RETURN_NONE;
    }
    return PyBool_FromLong(rc);
}

static PyObject *
pull(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    (void)module;
    return pull_with("pull", pull_locked, args, nargs);
}

/* pull_fd(reader, device, now, limit, kept, bad_limit): a pulled reader's pull of a hidraw
 * device (`hidapi_backend.HidapiDevice`, its own non-blocking fd `read_fd`) in one call, the
 * compiled form of `reader.DeviceReader.pull` over `HidapiDevice.read(0.0)`: the reports
 * queued read one a read() (no Python object made for each), then as `pull`. True, False
 * (declined: the Python pull runs), None (never) as `pull`. */
static PyObject *
pull_fd(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    (void)module;
    return pull_with("pull_fd", pull_fd_locked, args, nargs);
}

static PyMethodDef module_methods[] = {
    {"parse_events", parse_events, METH_O,
     "parse_events(lines) -> (times, reports), or None: not every line as hid-recorder writes"},
    {"parse_packed", parse_packed, METH_O,
     "parse_packed(text) -> (events, end, lines), or None: a line not as written"},
    {"pull", (PyCFunction)(void (*)(void))pull, METH_FASTCALL,
     "pull(reader, device, now, limit, kept, bad_limit) -> True pulled, False declined, None never"},
    {"pull_fd", (PyCFunction)(void (*)(void))pull_fd, METH_FASTCALL,
     "pull_fd(reader, device, now, limit, kept, bad_limit) -> as pull, for a hidraw fd"},
    {NULL, NULL, 0, NULL},
};

static PyMethodDef plan_methods[] = {
    {"drain", (PyCFunction)plan_drain, METH_VARARGS,
     "drain(batch, values, mask, edges) -> (accepted, refused, mask, "
     "changes)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject PlanType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "usb2rc.hid._speedups.Plan",
    .tp_basicsize = sizeof(PlanObject),
    .tp_dealloc = (destructor)plan_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "A device layout's reports, compiled for drain().",
    .tp_methods = plan_methods,
    .tp_init = (initproc)plan_init,
    .tp_new = PyType_GenericNew,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "_speedups",
    .m_doc = "The HID stage's optional C loops.",
    .m_size = -1,
    .m_methods = module_methods,
};

PyMODINIT_FUNC
PyInit__speedups(void)
{
    fill_hex_values();
    if (intern_pull_names() < 0) {
        return NULL;
    }
    if (PyType_Ready(&PlanType) < 0 || PyType_Ready(&EventsType) < 0) {
        return NULL;
    }
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) {
        return NULL;
    }
    if (PyModule_AddObjectRef(m, "Plan", (PyObject *)&PlanType) < 0
        || PyModule_AddObjectRef(m, "Events", (PyObject *)&EventsType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
