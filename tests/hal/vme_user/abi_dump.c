/* Prints the vendored ABI's facts as "name value" lines (tests/hal/vme_user/test_abi.py). */
#include <stddef.h>
#include <stdio.h>
#include "vme_user_abi.h"

#define SHOW(name, value) printf("%s %llu\n", name, (unsigned long long)(value))
#define LAYOUT(tag, type) do { \
	SHOW(tag ".sizeof", sizeof(type)); \
	SHOW(tag ".enable", offsetof(type, enable)); \
	SHOW(tag ".vme_addr", offsetof(type, vme_addr)); \
	SHOW(tag ".size", offsetof(type, size)); \
	SHOW(tag ".aspace", offsetof(type, aspace)); \
	SHOW(tag ".cycle", offsetof(type, cycle)); \
	SHOW(tag ".dwidth", offsetof(type, dwidth)); \
} while (0)

int main(void)
{
	LAYOUT("unpacked", struct vme_master_unpacked);
	LAYOUT("packed", struct vme_master_packed);
	SHOW("irq_id.sizeof", sizeof(struct vme_irq_id));
	SHOW("unpacked.get", VME_GET_MASTER_UNPACKED);
	SHOW("unpacked.set", VME_SET_MASTER_UNPACKED);
	SHOW("packed.get", VME_GET_MASTER_PACKED);
	SHOW("packed.set", VME_SET_MASTER_PACKED);
	SHOW("irq_gen", VME_IRQ_GEN);
	SHOW("A16", VME_A16); SHOW("A24", VME_A24); SHOW("A32", VME_A32);
	SHOW("SCT", VME_SCT); SHOW("BLT", VME_BLT);
	SHOW("SUPER", VME_SUPER); SHOW("USER", VME_USER); SHOW("PROG", VME_PROG); SHOW("DATA", VME_DATA);
	SHOW("D8", VME_D8); SHOW("D16", VME_D16); SHOW("D32", VME_D32);
	return 0;
}
