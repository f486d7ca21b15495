/* burst_check.c: every burst error of 1..16 bits, at every bit position of every given frame, through
 * the real receive state machine (hbp_rx_byte) -- none may be accepted.
 *
 * Input (file argument): one frame per line, hex, as decoded on the wire: type, seq, payload, CRC
 * (high byte first). A burst of length b (1 <= b <= 16) starting at bit s flips bit s and bit
 * s + b - 1 and any pattern in between (2^(b-2) patterns for b >= 2); bits are numbered MSB first
 * within each byte, bytes in wire order: the order in which the CRC divides. The corrupted frame is
 * COBS-encoded here (its own encoder, independent of hbp_encode_frame, which would recompute the
 * CRC), followed by the 0x00 delimiter, and fed byte by byte to hbp_rx_byte.
 * Build with -DHBP_RX_MAX=64u. Prints "bursts N accepted A frames F"; exit 0 iff A == 0.
 * With a second argument "wire" the bursts hit the COBS-encoded bytes instead (the delimiter kept):
 * then it only reports the count (a burst that rewrites a COBS code byte reshapes the whole frame)
 * and prints the first three accepted cases.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hbp.h"

#define MAX_FRAMES 256
#define LINE_CHARS 1024

static uint8_t frames[MAX_FRAMES][HBP_MAX_FRAME];
static unsigned frame_lens[MAX_FRAMES];

static unsigned cobs_encode(const uint8_t *raw, unsigned n, uint8_t *out)
{
    unsigned code_at = 0u;
    unsigned o = 1u;
    unsigned i;
    for (i = 0u; i < n; i++) {
        if (raw[i] == 0u) {
            out[code_at] = (uint8_t)(o - code_at);
            code_at = o++;
        } else {
            out[o++] = raw[i];
        }
    }
    out[code_at] = (uint8_t)(o - code_at);
    out[o++] = 0u;
    return o;
}

/* 1 if the receiver accepts any frame from these bytes (the receiver is reset first). */
static int accepted(const uint8_t *bytes, unsigned n)
{
    hbp_rx_t rx;
    unsigned i;
    int got = 0;
    hbp_rx_init(&rx);
    for (i = 0u; i < n; i++) {
        if (hbp_rx_byte(&rx, bytes[i])) {
            got = 1;
            hbp_rx_release(&rx);
        }
    }
    return got;
}

static void flip(uint8_t *buf, unsigned bit)
{
    buf[bit / 8u] = (uint8_t)(buf[bit / 8u] ^ (uint8_t)(0x80u >> (bit % 8u)));
}

/* Every burst over buf[0..n) (n bytes, bits MSB first); for each corrupted copy, check(copy). */
static unsigned long long run(const uint8_t *buf, unsigned n, int on_wire, unsigned long long *bad)
{
    unsigned long long count = 0u;
    unsigned nbits = 8u * n;
    unsigned start;
    uint8_t work[HBP_MAX_WIRE + 8u];
    uint8_t wire[HBP_MAX_WIRE + 8u];
    for (start = 0u; start < nbits; start++) {
        unsigned len;
        for (len = 1u; len <= 16u && start + len <= nbits; len++) {
            unsigned long pattern;
            unsigned long inner = (len >= 2u) ? (1ul << (len - 2u)) : 1ul;
            for (pattern = 0u; pattern < inner; pattern++) {
                unsigned j;
                unsigned w;
                memcpy(work, buf, n);
                flip(work, start);
                if (len >= 2u) {
                    flip(work, start + len - 1u);
                    for (j = 0u; j + 2u < len; j++) {
                        if ((pattern >> j) & 1ul) {
                            flip(work, start + 1u + j);
                        }
                    }
                }
                if (on_wire) {
                    work[n] = 0u; /* the delimiter is not hit (n excludes it) */
                    w = n + 1u;
                    if (accepted(work, w)) {
                        (*bad)++;
                        if (*bad <= 3u) {
                            unsigned q;
                            printf("accepted on the wire: burst of %u bits at bit %u:", len, start);
                            for (q = 0u; q < w; q++) {
                                printf(" %02x", work[q]);
                            }
                            printf("\n");
                        }
                    }
                } else {
                    w = cobs_encode(work, n, wire);
                    if (accepted(wire, w)) {
                        (*bad)++;
                        if (*bad <= 5u) {
                            printf("accepted: burst of %u bits at bit %u (pattern %lx)\n", len, start, pattern);
                        }
                    }
                }
                count++;
            }
        }
    }
    return count;
}

static int hexval(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int main(int argc, char **argv)
{
    FILE *f;
    char line[LINE_CHARS];
    unsigned nframes = 0u;
    unsigned k;
    unsigned long long total = 0u;
    unsigned long long bad = 0u;
    int on_wire = (argc > 2 && strcmp(argv[2], "wire") == 0);
    if (argc < 2 || (f = fopen(argv[1], "r")) == 0) {
        fprintf(stderr, "usage: burst_check FRAMES.txt [wire]\n");
        return 2;
    }
    while (fgets(line, sizeof line, f) != 0 && nframes < MAX_FRAMES) {
        unsigned n = 0u;
        char *p = line;
        while (hexval(p[0]) >= 0 && hexval(p[1]) >= 0 && n < HBP_MAX_FRAME) {
            frames[nframes][n++] = (uint8_t)(hexval(p[0]) * 16 + hexval(p[1]));
            p += 2;
        }
        if (n >= 4u) {
            frame_lens[nframes++] = n;
        }
    }
    fclose(f);
    for (k = 0u; k < nframes; k++) {
        uint8_t wire[HBP_MAX_WIRE + 8u];
        unsigned w = cobs_encode(frames[k], frame_lens[k], wire);
        if (!accepted(wire, w)) {
            printf("frame %u is not accepted uncorrupted\n", k);
            return 1;
        }
        if (on_wire) {
            total += run(wire, w - 1u, 1, &bad);
        } else {
            total += run(frames[k], frame_lens[k], 0, &bad);
        }
    }
    printf("bursts %llu accepted %llu frames %u\n", total, bad, nframes);
    return (bad == 0u || on_wire) ? 0 : 1;
}
