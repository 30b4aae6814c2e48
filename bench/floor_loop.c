/* The floor of the drivers' loop in C (bench/bench_floor.py builds and runs it): the same
 * shape as usb2rc's drivers' thread (usb2rc/lines/driver.py), with none of its features.
 *
 *   floor_loop LEAD_US --dev FD ... --out FD PERIOD_US LEN ...
 *
 * Every output ticks on the multiples of its period (monotonic clock). A tick starts LEAD_US
 * before its deadline: the devices are pulled (each report one read(2), as hidraw gives
 * them, until EAGAIN; the last one kept), and every output due within the lead makes its
 * frame (the kept report's bytes spread over LEN bytes, a CRC-16/XMODEM over them); on the
 * deadline the frames are written, one write(2) each. A tick whose start is a whole period
 * late is skipped. Runs until SIGTERM; prints nothing. */

#define _GNU_SOURCE
#include <errno.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define MAX_FDS 32
#define REPORT_MAX 256

struct output {
    int fd;
    int64_t period_ns;
    int len;
    int64_t deadline;
    int held;
    unsigned char frame[REPORT_MAX];
};

static volatile sig_atomic_t stopping;

static void on_term(int sig) { (void)sig; stopping = 1; }

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static void sleep_until(int64_t at)
{
    struct timespec ts = {at / 1000000000, at % 1000000000};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !stopping) {
    }
}

static uint16_t crc16_xmodem(const unsigned char *data, int n)
{
    uint16_t crc = 0;
    for (int i = 0; i < n; i++) {
        crc ^= (uint16_t)(data[i] << 8);
        for (int b = 0; b < 8; b++) {
            crc = crc & 0x8000 ? (uint16_t)(crc << 1 ^ 0x1021) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

int main(int argc, char **argv)
{
    int devs[MAX_FDS], ndev = 0, nout = 0;
    struct output outs[MAX_FDS];
    unsigned char state[REPORT_MAX] = {0}, buf[REPORT_MAX];
    int state_len = 1;
    int64_t lead = atoll(argv[1]) * 1000;
    for (int i = 2; i < argc; i++) {
        if (!strcmp(argv[i], "--dev") && i + 1 < argc && ndev < MAX_FDS) {
            devs[ndev++] = atoi(argv[++i]);
        } else if (!strcmp(argv[i], "--out") && i + 3 < argc && nout < MAX_FDS) {
            struct output *o = &outs[nout++];
            memset(o, 0, sizeof *o);
            o->fd = atoi(argv[++i]);
            o->period_ns = atoll(argv[++i]) * 1000;
            o->len = atoi(argv[++i]);
        } else {
            return 2;
        }
    }
    signal(SIGTERM, on_term);
    int64_t t0 = now_ns();
    for (int k = 0; k < nout; k++) {
        outs[k].deadline = (t0 / outs[k].period_ns + 1) * outs[k].period_ns;
    }
    while (!stopping) {
        /* the next moment: a held frame's deadline, else a tick's start */
        int64_t moment = INT64_MAX;
        for (int k = 0; k < nout; k++) {
            int64_t at = outs[k].held ? outs[k].deadline : outs[k].deadline - lead;
            moment = at < moment ? at : moment;
        }
        sleep_until(moment);
        int64_t now = now_ns();
        int wrote = 0;
        for (int k = 0; k < nout; k++) {
            struct output *o = &outs[k];
            if (o->held && o->deadline <= now) {
                ssize_t sent = write(o->fd, o->frame, (size_t)o->len);
                (void)sent;
                o->held = 0;
                o->deadline += o->period_ns;
                while (o->deadline - lead <= now_ns()) { /* missed: skipped */
                    o->deadline += o->period_ns;
                }
                wrote = 1;
            }
        }
        if (wrote) {
            continue;
        }
        for (int d = 0; d < ndev; d++) { /* the pull: a read per report, as hidraw */
            ssize_t n;
            while ((n = read(devs[d], buf, sizeof buf)) > 0) {
                memcpy(state, buf, (size_t)n);
                state_len = (int)n;
            }
        }
        for (int k = 0; k < nout; k++) {
            struct output *o = &outs[k];
            if (!o->held && o->deadline - lead <= now + 200000) {
                for (int i = 0; i < o->len - 2; i++) {
                    o->frame[i] = state[i % state_len];
                }
                uint16_t crc = crc16_xmodem(o->frame, o->len - 2);
                o->frame[o->len - 2] = (unsigned char)(crc >> 8);
                o->frame[o->len - 1] = (unsigned char)crc;
                o->held = 1;
            }
        }
    }
    return 0;
}
