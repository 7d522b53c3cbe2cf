/*
 * The Linux vme_user user-space ABI, vendored for tests/hal/vme_user/test_abi.py (which compiles
 * it with the system C compiler and compares sizes, offsets and request numbers with
 * hal/vme/vme_user_abi.py). Restated from the kernel's headers:
 *
 *   unpacked layout: drivers/staging/vme/devices/vme_user.h as of v3.10 (and before)
 *   packed layout:   drivers/staging/vme/devices/vme_user.h as of v3.18 and v4.x, and
 *                    drivers/staging/vme_user/vme_user.h in v5.x and v6.x (v6.6 checked)
 *   attribute bits:  include/linux/vme.h, later drivers/staging/vme_user/vme.h
 *
 * Both layouts are given here under their own names; the kernel calls both `struct vme_master`.
 */
#ifndef VMEHIL_VME_USER_ABI_H
#define VMEHIL_VME_USER_ABI_H

#include <linux/types.h>
#include <sys/ioctl.h>

#define VME_A16   0x1
#define VME_A24   0x2
#define VME_A32   0x4
#define VME_A64   0x8
#define VME_CRCSR 0x10

#define VME_SCT   0x1
#define VME_BLT   0x2
#define VME_MBLT  0x4
#define VME_SUPER 0x1000
#define VME_USER  0x2000
#define VME_PROG  0x4000
#define VME_DATA  0x8000

#define VME_D8  0x1
#define VME_D16 0x2
#define VME_D32 0x4
#define VME_D64 0x8

#define VME_IOC_MAGIC 0xAE

/* v3.10 and before: natural alignment (40 bytes on LP64, 32 on i386) */
struct vme_master_unpacked {
	int enable;
	unsigned long long vme_addr;
	unsigned long long size;
	__u32 aspace;
	__u32 cycle;
	__u32 dwidth;
};

/* v3.18 and later: __packed, 32 bytes everywhere */
struct vme_master_packed {
	__u32 enable;
	__u64 vme_addr;
	__u64 size;
	__u32 aspace;
	__u32 cycle;
	__u32 dwidth;
} __attribute__((packed));

struct vme_irq_id {
	__u8 level;
	__u8 statid;
};

#define VME_GET_MASTER_UNPACKED _IOR(VME_IOC_MAGIC, 3, struct vme_master_unpacked)
#define VME_SET_MASTER_UNPACKED _IOW(VME_IOC_MAGIC, 4, struct vme_master_unpacked)
#define VME_GET_MASTER_PACKED   _IOR(VME_IOC_MAGIC, 3, struct vme_master_packed)
#define VME_SET_MASTER_PACKED   _IOW(VME_IOC_MAGIC, 4, struct vme_master_packed)
#define VME_IRQ_GEN             _IOW(VME_IOC_MAGIC, 5, struct vme_irq_id)

#endif
