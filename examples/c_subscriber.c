/* c_subscriber.c: a lunad consumer in plain C. It applies docs/messages.md (schema v2) by
 * hand: exact topics, "v":2, duplicates and loss from run/seq/frames, cached messages,
 * and the subscriber's own staleness check. No JSON library: lunad's objects are flat.
 * Build: cc -O2 -Wall -Wextra -o c_subscriber c_subscriber.c -lzmq
 * Run:   ./c_subscriber ENDPOINT SENSOR [--count N] [--stale-ms M]   (M defaults to 200)
 * Prints "seq range_m status" per reading, then "received N lost L duplicates D".
 * Exits 0 after N readings or on SIGINT/SIGTERM, 3 after M ms without a reading
 * ("STALE"), 1 or 2 on errors. */
#include <errno.h>
#include <inttypes.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

static volatile sig_atomic_t stop;  /* SIGINT/SIGTERM: print the summary, exit 0 */
static void on_stop(int sig) { stop = sig; }

static int64_t now_ms(void) {  /* monotonic: immune to the wall clock being set */
    struct timespec ts;
    return clock_gettime(CLOCK_MONOTONIC, &ts), (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* Where the value of "key" starts in a flat JSON object, or NULL. lunad writes compact
 * JSON (no spaces), and `"key":` cannot occur inside a string: a quote there is `\"`. */
static const char *field(const char *js, const char *key) {
    char pat[40];
    int n = snprintf(pat, sizeof pat, "\"%s\":", key);
    const char *p = strstr(js, pat);
    return p ? p + n : NULL;
}

static int field_u64(const char *js, const char *key, uint64_t *out) {  /* 1: found */
    const char *p = field(js, key);  /* exact, unlike a double; 2^64 - 1: strtoull's overflow */
    return p && *p >= '0' && *p <= '9' && (*out = strtoull(p, NULL, 10)) != UINT64_MAX;
}
static int field_str(const char *js, const char *key, char *out, size_t cap) {
    const char *p = field(js, key);
    size_t len = p && *p == '"' ? strcspn(p + 1, "\"") : cap;
    if (len < cap) memcpy(out, p + 1, len), out[len] = '\0';
    return len < cap;  /* 0: absent, not a string, or longer than expected */
}

int main(int argc, char **argv) {
    uint64_t count = 0, v, seq, frames, age, received = 0, lost = 0, dups = 0, last = 0;
    long stale_ms = 200;  /* docs/messages.md: 0.2 s is a sensible limit at 250 Hz */
    int bad = argc < 3 || argc % 2 == 0 || !*argv[2] || strlen(argv[2]) > 64;  /* 1-64 chars */
    int code = 0, more, linger = 0;  /* linger 0: exit at once, even with the daemon gone */
    int64_t max_bytes = 1 << 20;  /* a longer message is not lunad's: not read, and lunad's
                                     own are at most 64 KiB (docs/messages.md) */
    for (int i = 3; i + 1 < argc; i += 2)  /* options come in pairs */
        if (!strcmp(argv[i], "--count")) count = strtoull(argv[i + 1], NULL, 10);
        else if (!strcmp(argv[i], "--stale-ms")) stale_ms = atol(argv[i + 1]);
        else bad = 1;
    if (bad || stale_ms <= 0)
        return fputs("usage: c_subscriber ENDPOINT SENSOR [--count N] [--stale-ms M]\n", stderr), 2;
    char rtopic[80], htopic[80], topic[80], js[4096], run[20], last_run[20] = "", status[16], *end;
    char name[72];
    struct sigaction sa = {.sa_handler = on_stop};  /* no SA_RESTART: zmq_poll returns EINTR */
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    snprintf(rtopic, sizeof rtopic, "range/%s/", argv[2]);
    snprintf(htopic, sizeof htopic, "health/%s/", argv[2]);
    void *ctx = zmq_ctx_new(), *sub = zmq_socket(ctx, ZMQ_SUB);
    zmq_setsockopt(sub, ZMQ_LINGER, &linger, sizeof linger);
    zmq_setsockopt(sub, ZMQ_MAXMSGSIZE, &max_bytes, sizeof max_bytes);
    /* The final "/" makes ZeroMQ's prefix match exact: range/front/ never gets range/frontleft/ */
    zmq_setsockopt(sub, ZMQ_SUBSCRIBE, rtopic, strlen(rtopic));
    zmq_setsockopt(sub, ZMQ_SUBSCRIBE, htopic, strlen(htopic));
    if (zmq_connect(sub, argv[1]) != 0)
        return fprintf(stderr, "%s: %s\n", argv[1], zmq_strerror(zmq_errno())), 1;
    int64_t last_ms = now_ms();  /* the silence clock starts now, before any message */
    zmq_pollitem_t item = {sub, 0, ZMQ_POLLIN, 0};
    while (!stop && (!count || received < count)) {
        long wait = (long)(last_ms + stale_ms - now_ms());  /* silence still allowed */
        int ready = wait > 0 ? zmq_poll(&item, 1, wait) : 0, tn, jn = -1, parts = 1;
        if (ready < 0 && zmq_errno() == EINTR) continue;  /* a signal: stop if it was ours */
        if (ready < 0) { perror("zmq_poll"); code = 1; break; }
        if (ready == 0) { printf("STALE no reading for %ld ms\n", stale_ms); code = 3; break; }
        tn = zmq_recv(sub, topic, sizeof topic - 1, 0);  /* lunad's messages: topic, JSON */
        while (zmq_getsockopt(sub, ZMQ_RCVMORE, &more, &(size_t){sizeof more}) == 0 && more)
            jn = zmq_recv(sub, js, sizeof js - 1, 0), parts++;
        if (parts != 2 || (size_t)tn >= sizeof topic || (size_t)jn >= sizeof js) continue;
        topic[tn] = js[jn] = '\0';
        if (!field_u64(js, "v", &v) || v != 2) { fprintf(stderr, "not schema v2\n"); continue; }
        if (!strcmp(topic, htopic) && field_str(js, "state", status, sizeof status))
            fprintf(stderr, "health %s\n", status);  /* about once a second */
        if (strcmp(topic, rtopic)) continue;  /* exact topics only, as subscribed */
        const char *r = field(js, "range_m"), *c = field(js, "cached");
        double range_m = r ? strtod(r, &end) : 0;  /* null: a dropout, never to act on */
        if (!r || !c || (end == r && strncmp(r, "null", 4)) || !field_u64(js, "seq", &seq) ||
            !field_u64(js, "frames", &frames) || !field_str(js, "run", run, sizeof run) ||
            !field_u64(js, "age_ms", &age) || !field_str(js, "status", status, sizeof status) ||
            !field_str(js, "sensor", name, sizeof name) || strcmp(name, argv[2]) ||
            (*r == 'n') != !strcmp(status, "dropout"))  /* null range exactly on a dropout */
            { fputs("malformed\n", stderr); continue; }
        if (!strcmp(run, last_run)) {  /* same run: seq rules; a new run starts the count again */
            if (seq <= last) { dups++; continue; }  /* e.g. the cache re-sent one we had */
            if (seq - last > frames) lost += seq - last - frames;  /* compare, then subtract */
        }
        strcpy(last_run, run), last = seq, received++;
        int64_t made = now_ms() - (*c == 't' ? (int64_t)age : 0);  /* cached: age_ms old */
        if (made > last_ms) last_ms = made;  /* so an old cached reading is no sign of life */
        if (*c == 't' && (int64_t)age > stale_ms)  /* cached, older than our limit: stale */
            printf("%" PRIu64 " null dropout", seq);
        else if (*r == 'n') printf("%" PRIu64 " null %s", seq, status);
        else printf("%" PRIu64 " %.4f %s", seq, range_m, status);
        printf("%s\n", *c == 't' ? " cached" : "");
        fflush(stdout);
    }
    printf("received %" PRIu64 " lost %" PRIu64 " duplicates %" PRIu64 "\n", received, lost, dups);
    zmq_close(sub);
    zmq_ctx_term(ctx);
    return code;
}
