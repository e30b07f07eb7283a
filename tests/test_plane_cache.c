/* The scene cache's files (sim/draw/plane_cache.h): rows written by several threads in any
 * order come back the same bits, the note with them; zero rows cost no disk; an entry missing
 * a row, or whose file was damaged (header, size or rows) or is another SCA's, is never used; entries beyond the
 * room go least recently used first; a folder that cannot be written fails no exposure. */
#include <fcntl.h>
#include <stdint.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "sim/draw/plane_cache.h"
#include "tests/testutil.h"

enum { W = 300, H = 200 };

static const char *key_of(int k)
{
    static char key[4][65];
    for (int i = 0; i < 64; i++) key[k][i] = "0123456789abcdef"[(i * 7 + k * 5) % 16];
    key[k][64] = '\0';
    return key[k];
}

/* The plane and layer of an entry k: rows of zeros every fourth row, and a sparse layer. */
static float plane_value(int k, int y, int x) { return y % 4 == 1 ? 0.0f : (float)(k + 1) * 0.001f * (float)(x * H + y) - 3.0f; }
static float layer_value(int k, int y, int x) { return y == 50 + k && x > 100 && x < 120 ? 1000.0f + (float)x : 0.0f; }

typedef struct writer { wf_plane_entry *e; int k, first, step; } writer;

static void *write_rows(void *arg)
{
    writer *w = arg;
    float p[W], l[W];
    for (int y = w->first; y >= 0 && y < H; y += w->step) {
        for (int x = 0; x < W; x++) p[x] = plane_value(w->k, y, x), l[x] = layer_value(w->k, y, x);
        wf_plane_entry_put(w->e, y, p, l, W);
        if (y % 3 == 0) wf_plane_entry_put(w->e, y, p, l, W); /* a tile's halo row, again */
    }
    return NULL;
}

/* Entry k written by two threads, one up and one down the rows. */
static void store(wf_plane_cache *c, int k)
{
    wf_plane_entry *e;
    int found;
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(k), W, H, 1, &e, &found), WF_OK);
    ck_assert_int_eq(found, 0);
    writer a = {e, k, 0, 2}, b = {e, k, H - 1, -2};
    pthread_t t;
    ck_assert_int_eq(pthread_create(&t, NULL, write_rows, &a), 0);
    write_rows(&b);
    pthread_join(t, NULL);
    char note[64];
    snprintf(note, sizeof note, "entry %d", k);
    wf_plane_entry_set_note(e, note);
    wf_plane_entry_close(e);
}

static int lookup(wf_plane_cache *c, int k, int layer)
{
    wf_plane_entry *e;
    int found;
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(k), W, H, layer, &e, &found), WF_OK);
    if (found) {
        static float p[W * H], l[W * H];
        ck_assert_int_eq(wf_plane_entry_get(e, 0, H, W, p, layer ? l : NULL), WF_OK);
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                ck_assert(p[y * W + x] == plane_value(k, y, x));
                if (layer) ck_assert(l[y * W + x] == layer_value(k, y, x));
            }
        ck_assert_int_eq(wf_plane_entry_get(e, 37, 41, W, p, NULL), WF_OK); /* a tile */
        ck_assert(p[W + 5] == plane_value(k, 38, 5));
        char want[64];
        snprintf(want, sizeof want, "entry %d", k);
        ck_assert_str_eq(wf_plane_entry_note(e), want);
    }
    wf_plane_entry_close(e);
    return found;
}

static const char *path_of(const char *dir, int k, char *buf, size_t cap)
{
    snprintf(buf, cap, "%s/%s.plane", dir, key_of(k));
    return buf;
}

START_TEST(round_trip_damage_and_room)
{
    char dir[4200], p[4400];
    snprintf(dir, sizeof dir, "%s/planes", wf_test_tmpdir());
    wf_plane_cache *c;
    /* the text header and a CRC-32 a row, to whole 4096 bytes, then the rows */
    const double entry = (double)((4096 + 2 * H * sizeof(uint32_t) + 4095) / 4096 * 4096) + 2.0 * W * H * sizeof(float);
    ck_assert_int_eq(wf_plane_cache_open(dir, 1e9, &c), WF_OK);
    ck_assert_int_eq(lookup(c, 0, 1), 0);
    store(c, 0);
    ck_assert_int_eq(lookup(c, 0, 1), 1);
    /* holes: a quarter of the plane's rows and all but one of the layer's are zeros */
    struct stat sb;
    ck_assert_int_eq(stat(path_of(dir, 0, p, sizeof p), &sb), 0);
    ck_assert_int_eq(sb.st_size, (off_t)entry);
    printf("plane cache: an entry of %.0f bytes takes %lld on disk\n", entry, (long long)sb.st_blocks * 512);
    ck_assert_msg((double)sb.st_blocks * 512.0 < 0.8 * entry, "zero rows were written");
    /* another SCA size, or asked without the layer it was stored with: not this entry */
    wf_plane_entry *e;
    int found;
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(0), W, H + 1, 1, &e, &found), WF_OK);
    ck_assert_int_eq(found, 0);
    wf_plane_entry_close(e); /* nothing written: nothing kept, the stored one stays */
    ck_assert_int_eq(lookup(c, 0, 0), 0);
    ck_assert_int_eq(lookup(c, 0, 1), 1);
    /* an entry missing a row is never kept */
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(1), W, H, 1, &e, &found), WF_OK);
    float row[W] = {1.0f};
    for (int y = 0; y < H - 1; y++) wf_plane_entry_put(e, y, row, row, W);
    wf_plane_entry_close(e);
    ck_assert_int_eq(lookup(c, 1, 1), 0);
    /* a damaged file (truncated; a header byte changed) is not used, and the next store
     * replaces it */
    ck_assert_int_eq(truncate(path_of(dir, 0, p, sizeof p), (off_t)entry - 4), 0);
    ck_assert_int_eq(lookup(c, 0, 1), 0);
    store(c, 0);
    ck_assert_int_eq(lookup(c, 0, 1), 1);
    int fd = open(p, O_WRONLY);
    ck_assert_int_ge(fd, 0);
    ck_assert_int_eq(pwrite(fd, "X", 1, 30), 1);
    close(fd);
    ck_assert_int_eq(lookup(c, 0, 1), 0);
    /* damage within the rows (a crash before the blocks reached the disk, a bad sector): the
     * header matches, but the rows read fail the exposure, never feed it, and the file goes */
    store(c, 0);
    const off_t rows_at = (off_t)((4096 + 2 * H * sizeof(uint32_t) + 4095) / 4096 * 4096);
    fd = open(p, O_WRONLY);
    ck_assert_int_ge(fd, 0);
    const float odd = 12345.0f;
    ck_assert_int_eq(pwrite(fd, &odd, sizeof odd, rows_at + (off_t)(10 * W + 8) * (off_t)sizeof(float)), sizeof odd);
    close(fd);
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(0), W, H, 1, &e, &found), WF_OK);
    ck_assert_int_eq(found, 1);
    static float rows[W * H];
    ck_assert_int_eq(wf_plane_entry_get(e, 0, 9, W, rows, NULL), WF_OK); /* rows above it are whole */
    ck_assert_int_eq(wf_plane_entry_get(e, 8, 12, W, rows, NULL), WF_ERR_IO);
    printf("plane cache: %s\n", wf_error_message());
    ck_assert(strstr(wf_error_message(), "row 10") != NULL);
    wf_plane_entry_close(e);
    ck_assert_int_ne(access(p, F_OK), 0);
    store(c, 0);
    ck_assert_int_eq(lookup(c, 0, 1), 1);
    fd = open(p, O_WRONLY);
    ck_assert_int_ge(fd, 0);
    ck_assert_int_eq(pwrite(fd, &odd, sizeof odd, rows_at + (off_t)(H + 50) * W * (off_t)sizeof(float) + 420), sizeof odd);
    close(fd);
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(0), W, H, 1, &e, &found), WF_OK);
    static float lrows[W * H];
    ck_assert_int_eq(wf_plane_entry_get(e, 40, 60, W, rows, lrows), WF_ERR_IO); /* the layer's row 50 */
    wf_plane_entry_close(e);
    ck_assert_int_eq(lookup(c, 0, 1), 0);
    wf_plane_cache_stats st;
    wf_plane_cache_get_stats(c, &st);
    /* asked for another size, and without the layer; the truncated file and the altered one,
     * each looked up and then replaced (damaged rows are found by their checksums instead) */
    ck_assert_int_eq(st.unusable, 6);
    ck_assert_int_eq(st.stored, 4);
    ck_assert_int_eq(st.evicted, 0);
    wf_plane_cache_close(c);
    /* room for two entries as they lie on disk: storing a third removes the least recently
     * used (the times set here: the file system's clock may not tell two stores a
     * millisecond apart) */
    ck_assert_int_eq(wf_plane_cache_open(dir, 2.5 * (double)sb.st_blocks * 512.0, &c), WF_OK);
    store(c, 0);
    store(c, 1);
    struct timespec old[2] = {{1000000, 0}, {1000000, 0}}, older[2] = {{999000, 0}, {999000, 0}};
    ck_assert_int_eq(utimensat(AT_FDCWD, path_of(dir, 0, p, sizeof p), old, 0), 0);
    ck_assert_int_eq(utimensat(AT_FDCWD, path_of(dir, 1, p, sizeof p), older, 0), 0);
    ck_assert_int_eq(lookup(c, 0, 1), 1); /* used now */
    store(c, 2);
    ck_assert_int_eq(lookup(c, 0, 1), 1);
    ck_assert_int_eq(lookup(c, 2, 1), 1);
    ck_assert_int_eq(lookup(c, 1, 1), 0);
    wf_plane_cache_get_stats(c, &st);
    ck_assert_int_eq(st.evicted, 1);
    ck_assert_int_eq(st.stored, 3);
    ck_assert_int_eq(st.not_kept, 0);
    /* a killed writer's temporary file goes once a day old, with the next store; a fresh one stays */
    char stale[4500], fresh[4500];
    snprintf(stale, sizeof stale, "%s.tmp.99999.7", path_of(dir, 3, p, sizeof p));
    snprintf(fresh, sizeof fresh, "%s.tmp.99999.8", path_of(dir, 3, p, sizeof p));
    FILE *tf = fopen(stale, "w"), *ff = fopen(fresh, "w");
    ck_assert(tf && ff);
    fclose(tf);
    fclose(ff);
    struct timespec day_old[2] = {{time(NULL) - 25 * 3600, 0}, {time(NULL) - 25 * 3600, 0}};
    ck_assert_int_eq(utimensat(AT_FDCWD, stale, day_old, 0), 0);
    store(c, 1);
    ck_assert_int_ne(access(stale, F_OK), 0);
    ck_assert_int_eq(access(fresh, F_OK), 0);
    ck_assert_int_eq(unlink(fresh), 0);
    /* no temporary file is left behind */
    char cmd[4400];
    snprintf(cmd, sizeof cmd, "test -z \"$(ls %s | grep tmp)\"", dir);
    ck_assert_int_eq(system(cmd), 0);
    wf_plane_cache_close(c);
}
END_TEST

/* A folder that cannot hold files (here a file is in its place once it was opened): the
 * entry is drawn and not kept, and the first reason is kept; the exposure goes on. */
START_TEST(unwritable_folder)
{
    char dir[4200];
    snprintf(dir, sizeof dir, "%s/gone", wf_test_tmpdir());
    wf_plane_cache *c;
    ck_assert_int_eq(wf_plane_cache_open(dir, 1e9, &c), WF_OK);
    ck_assert_int_eq(rmdir(dir), 0);
    FILE *f = fopen(dir, "w");
    ck_assert_ptr_nonnull(f);
    fclose(f);
    wf_plane_entry *e;
    int found;
    ck_assert_int_eq(wf_plane_entry_open(c, key_of(3), W, H, 0, &e, &found), WF_OK);
    ck_assert_int_eq(found, 0);
    float row[W] = {2.0f};
    for (int y = 0; y < H; y++) wf_plane_entry_put(e, y, row, NULL, W);
    wf_plane_entry_close(e);
    wf_plane_cache_stats st;
    wf_plane_cache_get_stats(c, &st);
    ck_assert_int_eq(st.not_kept, 1);
    ck_assert_int_eq(st.stored, 0);
    printf("plane cache: not kept: %s\n", st.reason);
    ck_assert(strstr(st.reason, dir) != NULL);
    wf_plane_cache_close(c);
    /* a folder name that is a file is refused when the cache is opened */
    ck_assert_int_ne(wf_plane_cache_open(dir, 1e9, &c), WF_OK);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("plane_cache");
    TCase *tc = tcase_create("plane_cache");
    tcase_add_test(tc, round_trip_damage_and_room);
    tcase_add_test(tc, unwritable_folder);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
