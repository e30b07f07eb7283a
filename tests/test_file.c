/* hal/file: products leave under a temporary name and are renamed into place only whole; a
 * failed rename leaves neither the product nor its temporary; folders a failed run made are
 * taken back when still empty. */
#include <check.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "hal/file.h"
#include "tests/testutil.h"

static int exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

START_TEST(text_commit_renames_whole)
{
    char path[4200], tmp[4300];
    const char *d = wf_test_tmpdir();
    snprintf(path, sizeof path, "%s/table.txt", d);
    FILE *f;
    ck_assert_int_eq(wf_file_text_open(path, tmp, sizeof tmp, &f), WF_OK);
    ck_assert(strncmp(tmp, path, strlen(path)) == 0 && exists(tmp) && !exists(path));
    fprintf(f, "a,b\n1,2\n");
    ck_assert_int_eq(wf_file_text_commit(f, tmp, path), WF_OK);
    ck_assert(!exists(tmp));
    size_t len;
    char *text = wf_test_slurp(path, &len);
    ck_assert_str_eq(text, "a,b\n1,2\n");
    free(text);
}
END_TEST

/* A rename that cannot happen (onto a folder that holds a file): WF_ERR_IO naming both
 * names, the temporary removed, the folder untouched. */
START_TEST(rename_failure_removes_tmp)
{
    char dir[4200], inside[4300], tmp[4300];
    const char *d = wf_test_tmpdir();
    snprintf(dir, sizeof dir, "%s/taken", d);
    snprintf(inside, sizeof inside, "%s/keep", dir);
    snprintf(tmp, sizeof tmp, "%s/product.tmp", d);
    ck_assert_int_eq(wf_file_make_dir(dir), WF_OK);
    FILE *f = fopen(inside, "w");
    fputs("x", f);
    fclose(f);
    f = fopen(tmp, "w");
    fputs("half a product", f);
    fclose(f);
    ck_assert_int_eq(wf_file_rename(tmp, dir), WF_ERR_IO);
    const char *msg = wf_error_message();
    ck_assert_msg(strstr(msg, dir) && strstr(msg, "product.tmp") && strstr(msg, "cannot rename"), "message '%s'", msg);
    ck_assert(!exists(tmp));
    ck_assert(exists(inside));
    /* and the plain case */
    f = fopen(tmp, "w");
    fputs("whole", f);
    fclose(f);
    snprintf(inside, sizeof inside, "%s/product.fits", d);
    ck_assert_int_eq(wf_file_rename(tmp, inside), WF_OK);
    ck_assert(!exists(tmp) && exists(inside));
}
END_TEST

/* mkdir -p notes the shallowest folder it made; undoing takes back only empty ones. */
START_TEST(made_folders_taken_back)
{
    char top[4200], deep[4300], made[WF_PATH_MAX];
    snprintf(top, sizeof top, "%s/new", wf_test_tmpdir());
    snprintf(deep, sizeof deep, "%s/a/b", top);
    ck_assert_int_eq(wf_file_make_dir_noting(deep, made), WF_OK);
    ck_assert_str_eq(made, top);
    ck_assert(exists(deep));
    wf_file_unmake_dir(deep, made);
    ck_assert(!exists(top));
    ck_assert_int_eq(wf_file_make_dir_noting(deep, made), WF_OK);
    char keep[4400];
    snprintf(keep, sizeof keep, "%s/a/keep.txt", top);
    FILE *f = fopen(keep, "w");
    fclose(f);
    wf_file_unmake_dir(deep, made); /* b goes, a holds a file and stays */
    ck_assert(!exists(deep) && exists(keep));
    ck_assert_int_eq(wf_file_make_dir_noting(deep, made), WF_OK);
    ck_assert_str_eq(made, deep); /* only b was new */
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("file");
    TCase *tc = tcase_create("core");
    tcase_add_test(tc, text_commit_renames_whole);
    tcase_add_test(tc, rename_failure_removes_tmp);
    tcase_add_test(tc, made_folders_taken_back);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
