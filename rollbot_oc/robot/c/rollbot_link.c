/* rollbot_link.c - the robot link's wire protocol, robot side (see rollbot_link.h).  C99, no heap, no stdio. */
#include "rollbot_link.h"

#include <float.h>
#include <math.h>
#include <string.h>

/* the wire carries IEEE-754 binary64 (times, accelerations) and binary32 (the state): the target's double must
   be 8 bytes */
typedef char rl_double_is_64_bits[(sizeof(double) == 8) ? 1 : -1];

/* --- little-endian fields ------------------------------------------------------------------------------ */

static void put_u16(uint8_t *p, uint16_t v) {
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

static void put_u64(uint8_t *p, uint64_t v) {
    put_u32(p, (uint32_t)(v & 0xFFFFFFFFu));
    put_u32(p + 4, (uint32_t)(v >> 32));
}

static void put_f64(uint8_t *p, double x) {
    uint64_t v;
    memcpy(&v, &x, sizeof v);
    put_u64(p, v);
}

static void put_f32(uint8_t *p, double x) {
    /* round to single precision as the Python side does; beyond its range (where the cast is undefined),
       infinite */
    const double lim = (double)FLT_MAX + 10141204801825835211973625643008.0; /* FLT_MAX + 2^103 */
    float f = (x >= lim) ? HUGE_VALF : (x <= -lim) ? -HUGE_VALF : (x > (double)FLT_MAX) ? FLT_MAX
              : (x < -(double)FLT_MAX) ? -FLT_MAX : (float)x;
    uint32_t v;
    memcpy(&v, &f, sizeof v);
    put_u32(p, v);
}

static uint16_t get_u16(const uint8_t *p) {
    return (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static double get_f64(const uint8_t *p) {
    uint64_t v = (uint64_t)get_u32(p) | ((uint64_t)get_u32(p + 4) << 32);
    double x;
    memcpy(&x, &v, sizeof x);
    return x;
}

static double get_f32(const uint8_t *p) {
    uint32_t v = get_u32(p);
    float x;
    memcpy(&x, &v, sizeof x);
    return (double)x;
}

/* --- CRC-32 and COBS ------------------------------------------------------------------------------------ */

uint32_t rl_crc32(const uint8_t *data, size_t n) {
    uint32_t crc = 0xFFFFFFFFu;
    size_t i;
    int k;
    for (i = 0; i < n; i++) {
        crc ^= data[i];
        for (k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return crc ^ 0xFFFFFFFFu;
}

int32_t rl_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t cap) {
    size_t read = 0, write = 1, code_at = 0;
    uint8_t code = 1;
    if (cap < 1) return RL_ERR_BUFFER;
    while (read < n) {
        if (in[read] == 0) {
            out[code_at] = code;
            code_at = write++;
            code = 1;
            if (code_at >= cap) return RL_ERR_BUFFER;
        } else {
            if (write >= cap) return RL_ERR_BUFFER;
            out[write++] = in[read];
            code++;
            if (code == 0xFF) {
                out[code_at] = code;
                code_at = write++;
                code = 1;
                if (code_at >= cap) return RL_ERR_BUFFER;
            }
        }
        read++;
    }
    out[code_at] = code;
    return (int32_t)write;
}

int32_t rl_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap) {
    size_t i = 0, write = 0, j;
    if (n == 0) return RL_ERR_COBS;
    while (i < n) {
        uint8_t code = in[i];
        if (code == 0 || i + code > n) return RL_ERR_COBS;
        for (j = i + 1; j < i + code; j++) {
            if (in[j] == 0) return RL_ERR_COBS;
            if (write >= cap) return RL_ERR_BUFFER;
            out[write++] = in[j];
        }
        i += code;
        if (code < 0xFF && i < n) {
            if (write >= cap) return RL_ERR_BUFFER;
            out[write++] = 0;
        }
    }
    return (int32_t)write;
}

/* --- messages ------------------------------------------------------------------------------------------- */

/* the payload of msg into p (RL_MAX_PAYLOAD bytes); its length or RL_ERR_TYPE / RL_ERR_PAYLOAD */
static int32_t pack_payload(const rl_message_t *msg, uint8_t *p) {
    int i;
    switch (msg->type) {
    case RL_HEARTBEAT:
        put_u32(p, msg->body.heartbeat.time_ms);
        p[4] = msg->body.heartbeat.mode;
        return 5;
    case RL_MEASUREMENT:
        put_u32(p, msg->body.measurement.period);
        put_f64(p + 4, msg->body.measurement.time);
        for (i = 0; i < RL_STATE_SIZE; i++) put_f32(p + 12 + 4 * i, msg->body.measurement.state[i]);
        return 12 + 4 * RL_STATE_SIZE;
    case RL_COMMAND:
        put_u32(p, msg->body.command.period);
        put_f64(p + 4, msg->body.command.acceleration);
        p[12] = msg->body.command.status;
        return 13;
    case RL_PLAN_CHUNK: {
        const rl_plan_chunk_t *c = &msg->body.plan_chunk;
        if (c->count == 0 || c->index >= c->count || c->length > RL_MAX_CHUNK) return RL_ERR_PAYLOAD;
        put_u16(p, c->plan_id);
        put_u16(p + 2, c->index);
        put_u16(p + 4, c->count);
        memcpy(p + RL_PLAN_HEADER_BYTES, c->data, c->length);
        return RL_PLAN_HEADER_BYTES + (int32_t)c->length;
    }
    case RL_MODE:
        p[0] = msg->body.mode.mode;
        put_u32(p + 1, msg->body.mode.tick);
        p[5] = msg->body.mode.reason;
        return 6;
    default:
        return RL_ERR_TYPE;
    }
}

/* the payload p of n bytes into msg (its type set); RL_OK or RL_ERR_PAYLOAD */
static int32_t unpack_payload(const uint8_t *p, size_t n, rl_message_t *msg) {
    int i;
    switch (msg->type) {
    case RL_HEARTBEAT:
        if (n != 5) return RL_ERR_PAYLOAD;
        msg->body.heartbeat.time_ms = get_u32(p);
        msg->body.heartbeat.mode = p[4];
        return RL_OK;
    case RL_MEASUREMENT:
        if (n != 12 + 4 * RL_STATE_SIZE) return RL_ERR_PAYLOAD;
        msg->body.measurement.period = get_u32(p);
        msg->body.measurement.time = get_f64(p + 4);
        for (i = 0; i < RL_STATE_SIZE; i++) msg->body.measurement.state[i] = get_f32(p + 12 + 4 * i);
        return RL_OK;
    case RL_COMMAND:
        if (n != 13) return RL_ERR_PAYLOAD;
        msg->body.command.period = get_u32(p);
        msg->body.command.acceleration = get_f64(p + 4);
        msg->body.command.status = p[12];
        return RL_OK;
    case RL_PLAN_CHUNK: {
        rl_plan_chunk_t *c = &msg->body.plan_chunk;
        if (n < RL_PLAN_HEADER_BYTES || n > RL_MAX_PAYLOAD) return RL_ERR_PAYLOAD;
        c->plan_id = get_u16(p);
        c->index = get_u16(p + 2);
        c->count = get_u16(p + 4);
        if (c->count == 0 || c->index >= c->count) return RL_ERR_PAYLOAD;
        c->length = (uint16_t)(n - RL_PLAN_HEADER_BYTES);
        memcpy(c->data, p + RL_PLAN_HEADER_BYTES, c->length);
        return RL_OK;
    }
    case RL_MODE:
        if (n != 6) return RL_ERR_PAYLOAD;
        msg->body.mode.mode = p[0];
        msg->body.mode.tick = get_u32(p + 1);
        msg->body.mode.reason = p[5];
        return RL_OK;
    default:
        return RL_ERR_TYPE;
    }
}

int32_t rl_encode(const rl_message_t *msg, uint8_t *out, size_t cap) {
    uint8_t packet[RL_MAX_PACKET];
    int32_t n = pack_payload(msg, packet + RL_HEADER_BYTES), m;
    if (n < 0) return n;
    packet[0] = RL_VERSION;
    packet[1] = msg->type;
    put_u16(packet + 2, msg->seq);
    put_u16(packet + 4, (uint16_t)n);
    n += RL_HEADER_BYTES;
    put_u32(packet + n, rl_crc32(packet, (size_t)n));
    n += RL_CRC_BYTES;
    if (cap < 1) return RL_ERR_BUFFER;
    m = rl_cobs_encode(packet, (size_t)n, out, cap - 1);
    if (m < 0) return m;
    out[m] = 0;
    return m + 1;
}

int32_t rl_decode_frame(const uint8_t *frame, size_t n, rl_message_t *msg) {
    uint8_t packet[RL_MAX_PACKET];
    int32_t m = rl_cobs_decode(frame, n, packet, sizeof packet);
    uint16_t length;
    if (m == RL_ERR_BUFFER) return RL_ERR_LENGTH;
    if (m < 0) return m;
    if (m < RL_HEADER_BYTES + RL_CRC_BYTES) return RL_ERR_LENGTH;
    if (rl_crc32(packet, (size_t)(m - RL_CRC_BYTES)) != get_u32(packet + m - RL_CRC_BYTES)) return RL_ERR_CRC;
    length = get_u16(packet + 4);
    if ((int32_t)length != m - RL_HEADER_BYTES - RL_CRC_BYTES || length > RL_MAX_PAYLOAD) return RL_ERR_LENGTH;
    if (packet[0] != RL_VERSION) return RL_ERR_VERSION;
    if (packet[1] < RL_HEARTBEAT || packet[1] > RL_MODE) return RL_ERR_TYPE;
    msg->type = packet[1];
    msg->seq = get_u16(packet + 2);
    return unpack_payload(packet + RL_HEADER_BYTES, length, msg);
}

/* --- streaming decoder ---------------------------------------------------------------------------------- */

void rl_decoder_init(rl_decoder_t *dec) {
    memset(dec, 0, sizeof *dec);
}

uint32_t rl_decoder_dropped(const rl_decoder_t *dec) {
    return dec->err_cobs + dec->err_crc + dec->err_length + dec->err_version + dec->err_type
        + dec->err_payload + dec->err_overflow;
}

/* Count a decoded sequence number against those decoded so far (as the Python Decoder does). */
static void rl_sequence(rl_decoder_t *dec, uint16_t seq) {
    uint16_t ahead = (uint16_t)(seq - dec->last_seq), back = (uint16_t)(dec->last_seq - seq);
    if (!dec->have_seq) {
        dec->have_seq = 1;
        dec->last_seq = seq;
        dec->seen = 1u;
    } else if (ahead > 0u && ahead < 32768u) {
        dec->missed += (uint32_t)ahead - 1u;
        dec->seen = ahead < RL_SEQ_WINDOW ? (dec->seen << ahead) | 1u : 1u;
        dec->last_seq = seq;
    } else if (back < RL_SEQ_WINDOW && ((dec->seen >> back) & 1u)) {
        dec->duplicates++;
    } else {
        dec->late++;
        if (back < RL_SEQ_WINDOW) dec->seen |= 1u << back;
    }
}

int rl_decoder_push(rl_decoder_t *dec, uint8_t byte, rl_message_t *msg) {
    int32_t r;
    if (byte != 0) {
        if (dec->discarding) return 0;
        if (dec->len >= RL_MAX_ENCODED) {
            dec->err_overflow++;
            dec->len = 0;
            dec->discarding = 1;
            return 0;
        }
        dec->buf[dec->len++] = byte;
        return 0;
    }
    if (dec->discarding) {
        dec->discarding = 0;
        return 0;
    }
    if (dec->len == 0) return 0; /* an empty frame: skipped, not counted */
    r = rl_decode_frame(dec->buf, dec->len, msg);
    dec->len = 0;
    switch (r) {
    case RL_OK:
        rl_sequence(dec, msg->seq);
        dec->frames++;
        return 1;
    case RL_ERR_COBS: dec->err_cobs++; break;
    case RL_ERR_CRC: dec->err_crc++; break;
    case RL_ERR_LENGTH: dec->err_length++; break;
    case RL_ERR_VERSION: dec->err_version++; break;
    case RL_ERR_TYPE: dec->err_type++; break;
    default: dec->err_payload++; break;
    }
    return 0;
}
