/* burst_check.c: every single-bit error and every burst of 2..16 bits, at every bit position of a
 * stream holding one frame -- its leading delimiter, the frame's wire bytes, its delimiter and one
 * idle filler byte -- through the real receive state machine (hbp_rx_byte). An error that touches
 * the frame or either delimiter must leave no frame accepted; one that touches only the idle byte
 * must leave exactly the original accepted (the error is the next frame's, and it is rejected there).
 *
 * Input (file argument): one frame per line, hex, its wire bytes without the delimiter. A burst of
 * length b starting at bit s flips bits s and s + b - 1 and any pattern in between (2^(b-2)
 * patterns for b >= 2); bits are numbered MSB first within each byte, bytes in wire order (the
 * order in which the CRC divides). The receiver's state after the bytes before the burst is
 * computed once per start byte, so each case feeds only the rest.
 * Prints "streams N bursts B accepted A"; exit 0 iff A == 0.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hbp.h"

#define MAX_FRAMES 256
#define LINE_CHARS 1024
#define MAX_STREAM (HBP_MAX_WIRE + 4u)

static hbp_u8 frames[MAX_FRAMES][MAX_STREAM];
static unsigned frame_lens[MAX_FRAMES];

/* Feed bytes[from..n) to a copy of rx; the number of frames accepted, and whether the last one
 * accepted equals want (want_len bytes). */
static unsigned feed(const hbp_rx_t *start, const hbp_u8 *bytes, unsigned from, unsigned n, const hbp_u8 *want,
                     unsigned want_len, int *equal)
{
    hbp_rx_t rx = *start;
    unsigned i;
    unsigned got = 0u;
    for (i = from; i < n; i++) {
        if (hbp_rx_byte(&rx, bytes[i])) {
            got++;
            *equal = (rx.frame_len == want_len && memcmp(rx.buf, want, want_len) == 0);
            hbp_rx_release(&rx);
        }
    }
    return got;
}

int main(int argc, char **argv)
{
    static char line[LINE_CHARS];
    FILE *f;
    unsigned n_frames = 0u;
    unsigned k;
    unsigned long long bursts = 0u;
    unsigned long long bad = 0u;
    if (argc < 2 || (f = fopen(argv[1], "r")) == 0) {
        fprintf(stderr, "usage: burst_check FRAMES.hex\n");
        return 2;
    }
    while (fgets(line, sizeof line, f) != 0 && n_frames < MAX_FRAMES) {
        unsigned len = 0u;
        char *p = line;
        unsigned v;
        int used;
        frames[n_frames][len++] = 0u; /* the leading delimiter */
        while (sscanf(p, "%2x%n", &v, &used) == 1 && len < MAX_STREAM - 2u) {
            frames[n_frames][len++] = (hbp_u8)v;
            p += used;
        }
        if (len < 2u) {
            continue;
        }
        frames[n_frames][len++] = 0u; /* its delimiter */
        frames[n_frames][len++] = 0u; /* idle filler */
        frame_lens[n_frames++] = len;
    }
    fclose(f);
    for (k = 0u; k < n_frames; k++) {
        const hbp_u8 *orig = frames[k];
        unsigned n = frame_lens[k];
        unsigned nbits = 8u * n;
        unsigned idle_bit = 8u * (n - 1u); /* the first bit of the idle byte */
        hbp_u8 want[HBP_RX_MAX];
        unsigned want_len;
        hbp_rx_t clean;
        hbp_u8 work[MAX_STREAM];
        unsigned start;
        int equal = 0;
        hbp_rx_init(&clean);
        if (feed(&clean, orig, 0u, n, want, 0u, &equal) != 1u) {
            printf("frame %u: the uncorrupted stream is not one frame\n", k);
            return 1;
        }
        { /* the original message, as the receiver keeps it */
            hbp_rx_t rx;
            unsigned i;
            hbp_rx_init(&rx);
            for (i = 0u; i < n && !hbp_rx_byte(&rx, orig[i]); i++) {
            }
            want_len = rx.frame_len;
            memcpy(want, rx.buf, want_len);
        }
        for (start = 0u; start < nbits; start++) {
            hbp_rx_t before;
            unsigned byte0 = start / 8u;
            unsigned i;
            unsigned len;
            unsigned early = 0u; /* frames accepted before the burst's first byte (the original's) */
            hbp_rx_init(&before);
            for (i = 0u; i < byte0; i++) {
                if (hbp_rx_byte(&before, orig[i])) {
                    early++;
                    hbp_rx_release(&before);
                }
            }
            for (len = 1u; len <= 16u && start + len <= nbits; len++) {
                unsigned long inner = (len >= 2u) ? (1ul << (len - 2u)) : 1ul;
                unsigned long pattern;
                for (pattern = 0u; pattern < inner; pattern++) {
                    unsigned j;
                    unsigned got;
                    memcpy(work, orig, n);
                    work[start / 8u] ^= (hbp_u8)(0x80u >> (start % 8u));
                    if (len >= 2u) {
                        unsigned last = start + len - 1u;
                        work[last / 8u] ^= (hbp_u8)(0x80u >> (last % 8u));
                        for (j = 0u; j + 2u <= len; j++) {
                            if ((pattern >> j) & 1ul) {
                                unsigned b = start + 1u + j;
                                work[b / 8u] ^= (hbp_u8)(0x80u >> (b % 8u));
                            }
                        }
                    }
                    equal = (early > 0u);
                    got = early + feed(&before, work, byte0, n, want, want_len, &equal);
                    bursts++;
                    if (start >= idle_bit ? !(got == 1u && equal) : got != 0u) {
                        if (bad < 3u) {
                            printf("frame %u: burst at bit %u, %u bits, pattern %lx: %u frames accepted\n", k, start,
                                   len, pattern, got);
                        }
                        bad++;
                    }
                }
            }
        }
    }
    printf("streams %u bursts %llu accepted %llu\n", n_frames, bursts, bad);
    return bad == 0u ? 0 : 1;
}
