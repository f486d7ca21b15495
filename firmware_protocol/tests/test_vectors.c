/* test_vectors.c: checks every golden vector with the C library.
 *
 * For each vector the wire bytes go one at a time through the receive state machine (as from a UART
 * ISR). At each delimiter that ends a non-empty chunk the outcome is compared with the next `expect`
 * line: a good frame is unpacked, compared field by field, packed again and re-encoded (the bytes
 * must be identical, both through hbp_encode_frame and through the streaming hbp_send_frame); an error
 * must be counted with the expected kind. Build with -DHBP_RX_MAX=63u.
 * Usage: test_vectors VECTORS.txt   -> prints "N vectors ok", exit 0; or the first failure, exit 1.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hbp.h"
#include "hbp_test_fields.h"

#define MAX_WIRE 512

static hbp_u8 sent[HBP_MAX_WIRE];
static unsigned sent_len;

static void put(const hbp_u8 *bytes, hbp_u8 n)
{
    unsigned i;
    for (i = 0u; i < n && sent_len < sizeof sent; i++) {
        sent[sent_len++] = bytes[i];
    }
}
#define MAX_EXPECTS 8
#define LINE_MAX_CHARS 4096

typedef struct {
    char name[64];
    hbp_u8 wire[MAX_WIRE];
    unsigned wire_len;
    char expects[MAX_EXPECTS][LINE_MAX_CHARS];
    unsigned n_expects;
    int hello; /* -1 none, 0 reject, 1 accept */
} vector_t;

static int fail(const vector_t *v, const char *what)
{
    printf("FAIL %s: %s\n", v->name, what);
    return 1;
}

static const char *error_kind(hbp_u8 code)
{
    switch (code) {
    case HBP_ERROR_CRC: return "crc";
    case HBP_ERROR_COBS: return "cobs";
    case HBP_ERROR_LENGTH: return "length";
    case HBP_ERROR_UNKNOWN_TYPE: return "unknown_type";
    case HBP_ERROR_OVERSIZED: return "oversized";
    default: return "?";
    }
}

/* Compare an unpacked message with "Name f=v f=v ..." */
static int check_fields(const vector_t *v, hbp_u8 type, const hbp_any_t *m, const char *expect)
{
    char buf[LINE_MAX_CHARS];
    char *tok;
    const char *name = hbp_test_name(type);
    strncpy(buf, expect, sizeof buf - 1u);
    buf[sizeof buf - 1u] = '\0';
    tok = strtok(buf, " ");
    if (name == 0 || tok == 0 || strcmp(tok, name) != 0) {
        return fail(v, "message type differs");
    }
    while ((tok = strtok(0, " ")) != 0) {
        char *eq = strchr(tok, '=');
        long long value = 0;
        unsigned count = 0u;
        const char *str = 0;
        int kind;
        if (eq == 0) {
            return fail(v, "bad expect token");
        }
        *eq = '\0';
        kind = hbp_test_field(type, m, tok, 0u, &value, &count, &str);
        if (kind == 1) {
            if (value != strtoll(eq + 1, 0, 10)) {
                printf("field %s: got %lld want %s\n", tok, value, eq + 1);
                return fail(v, "scalar field differs");
            }
        } else if (kind == 3) {
            if (strcmp(str, eq + 1) != 0) {
                return fail(v, "string field differs");
            }
        } else if (kind == 2) {
            const char *p = eq + 1;
            unsigned i = 0u;
            while (*p != '\0') {
                char *end;
                long long want = strtoll(p, &end, 10);
                (void)hbp_test_field(type, m, tok, i, &value, &count, &str);
                if (i >= count || value != want) {
                    printf("field %s[%u]: want %lld\n", tok, i, want);
                    return fail(v, "array field differs");
                }
                i++;
                p = (*end == ',') ? end + 1 : end;
            }
            (void)hbp_test_field(type, m, tok, 0u, &value, &count, &str);
            if (i != count) {
                return fail(v, "array length differs");
            }
        } else {
            printf("field %s\n", tok);
            return fail(v, "unknown field");
        }
    }
    return 0;
}

static int run_vector(const vector_t *v)
{
    static hbp_rx_t rx; /* static: the sanitizer build checks the same layout as a firmware */
    unsigned i;
    unsigned chunk_start = 0u;
    unsigned next = 0u;
    hbp_rx_init(&rx);
    for (i = 0u; i < v->wire_len; i++) {
        hbp_u8 byte = v->wire[i];
        hbp_u8 got = hbp_rx_byte(&rx, byte); /* a chunk's outcome is known at its delimiter */
        if (byte != 0u) {
            continue;
        }
        if (i == chunk_start) { /* empty chunk: idle delimiter */
            chunk_start = i + 1u;
            continue;
        }
        if (next >= v->n_expects) {
            return fail(v, "more chunks than expects");
        }
        {
            const char *expect = v->expects[next];
            next++;
            if (got) {
                hbp_any_t m;
                hbp_u8 frame[HBP_MAX_FRAME];
                hbp_u8 out[HBP_MAX_WIRE];
                hbp_u8 type = rx.buf[0];
                hbp_u8 res = hbp_test_unpack(rx.buf, rx.frame_len, &m);
                hbp_u8 flen;
                hbp_u8 wlen;
                if (res != HBP_ERROR_NONE) {
                    hbp_rx_release(&rx);
                    if (strncmp(expect, "error ", 6) != 0 || strcmp(expect + 6, error_kind(res)) != 0) {
                        printf("unpack said %s, expected '%s'\n", error_kind(res), expect);
                        return fail(v, "unexpected unpack error");
                    }
                    chunk_start = i + 1u;
                    continue;
                }
                if (strncmp(expect, "error ", 6) == 0) {
                    return fail(v, "accepted a frame that should fail");
                }
                if (check_fields(v, type, &m, expect) != 0) {
                    return 1;
                }
                if (v->hello >= 0) {
                    hbp_host_hello_t h;
                    hbp_u8 r = hbp_check_hello(&m.host_hello);
                    hbp_u8 r2 = hbp_check_host_hello(rx.buf, rx.frame_len, &h);
                    if ((r == HBP_ERROR_NONE) != (v->hello == 1) || r2 != r) {
                        return fail(v, "hello check differs");
                    }
                }
                flen = hbp_test_pack(type, &m, frame);
                wlen = hbp_encode_frame(frame, flen, out);
                if (wlen != i + 1u - chunk_start || memcmp(out, &v->wire[chunk_start], wlen) != 0) {
                    return fail(v, "re-encoded bytes differ");
                }
                sent_len = 0u;
                hbp_send_frame(frame, flen, put);
                if (sent_len != wlen || memcmp(sent, out, wlen) != 0) {
                    return fail(v, "streamed bytes differ");
                }
                memcpy(&out[2], frame, flen); /* in place, as the runtime's link once packed */
                if (hbp_encode_frame(&out[2], flen, out) != wlen || memcmp(out, &v->wire[chunk_start], wlen) != 0) {
                    return fail(v, "in-place encoding differs");
                }
                hbp_rx_release(&rx);
            } else {
                const char *kind = error_kind(rx.last_error);
                if (strncmp(expect, "error ", 6) != 0) {
                    printf("rejected with %s\n", kind);
                    return fail(v, "rejected a good frame");
                }
                if (strcmp(expect + 6, kind) != 0) {
                    printf("got %s, expected %s\n", kind, expect + 6);
                    return fail(v, "wrong error kind");
                }
            }
        }
        chunk_start = i + 1u;
    }
    if (next != v->n_expects) {
        return fail(v, "fewer chunks than expects");
    }
    return 0;
}

static unsigned parse_hex(const char *s, hbp_u8 *out, unsigned cap)
{
    unsigned n = 0u;
    while (*s != '\0' && *s != '\n' && n < cap) {
        char *end;
        unsigned long b = strtoul(s, &end, 16);
        if (end == s) {
            break;
        }
        out[n++] = (hbp_u8)b;
        s = end;
    }
    return n;
}

int main(int argc, char **argv)
{
    static vector_t v;
    static char line[LINE_MAX_CHARS];
    unsigned count = 0u;
    FILE *f;
    if (argc != 2) {
        fprintf(stderr, "usage: %s VECTORS.txt\n", argv[0]);
        return 2;
    }
    f = fopen(argv[1], "r");
    if (f == 0) {
        perror(argv[1]);
        return 2;
    }
    while (fgets(line, sizeof line, f) != 0) {
        size_t len = strlen(line);
        if (len > 0u && line[len - 1u] == '\n') {
            line[len - 1u] = '\0';
        }
        if (strncmp(line, "vector ", 7) == 0) {
            memset(&v, 0, sizeof v);
            v.hello = -1;
            strncpy(v.name, line + 7, sizeof v.name - 1u);
        } else if (strncmp(line, "wire ", 5) == 0) {
            v.wire_len = parse_hex(line + 5, v.wire, MAX_WIRE);
        } else if (strncmp(line, "expect ", 7) == 0) {
            if (v.n_expects >= MAX_EXPECTS) {
                fclose(f);
                return fail(&v, "too many expects");
            }
            strncpy(v.expects[v.n_expects], line + 7, LINE_MAX_CHARS - 1u);
            v.n_expects++;
        } else if (strncmp(line, "hello ", 6) == 0) {
            v.hello = (strcmp(line + 6, "accept") == 0) ? 1 : 0;
        } else if (strcmp(line, "end") == 0) {
            if (run_vector(&v) != 0) {
                fclose(f);
                return 1;
            }
            count++;
        }
    }
    fclose(f);
    printf("%u vectors ok\n", count);
    return count > 0u ? 0 : 1;
}
